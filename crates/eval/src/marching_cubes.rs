//! Marching cubes (Lorensen & Cline 1987) over a regular grid of samples, one z-plane at a
//! time, so that a 2049³ grid needs only two planes of values in memory.
//!
//! A sample is *inside* when its value is at least the level (NaN is outside). Each cell's
//! triangles come from a case table that is not typed in but derived once from the cube's
//! faces: on each face, walked counter-clockwise as seen from outside the cell, every run of
//! inside corners gives one directed segment from the edge where the walk leaves the run to
//! the edge where it entered it; the segments chain into closed polygons (every crossed edge
//! starts one segment and ends another), which are fanned into triangles. On a face with two
//! diagonally opposite inside corners the rule keeps them apart; because it looks only at the
//! face's own four corners, the two cells sharing a face cut it identically (in opposite
//! directions), so the surface is closed and consistently oriented wherever it does not leave
//! the grid. Vertices lie on cell edges at the linearly interpolated crossing and are shared
//! between the cells around an edge. Triangles are counter-clockwise seen from outside: their
//! normals point from inside (high values) to outside.
//!
//! ```
//! use eval::marching_cubes::{GridSpec, marching_cubes};
//! // A ball of radius 0.3 in the unit cube, sampled at 33³ points.
//! let grid = GridSpec { dims: [33; 3], origin: [0.0; 3], spacing: [1.0 / 32.0; 3] };
//! let mesh = marching_cubes(&grid, 0.0, |z| {
//!     let mut plane = Vec::with_capacity(33 * 33);
//!     for y in 0..33 {
//!         for x in 0..33 {
//!             let p = [x, y, z].map(|i| i as f64 / 32.0 - 0.5);
//!             plane.push((0.3 - (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt()) as f32);
//!         }
//!     }
//!     plane
//! }, &mut |_, _| {});
//! let area = 4.0 * std::f64::consts::PI * 0.09;
//! assert!((mesh.area() / area - 1.0).abs() < 0.02);
//! ```

use crate::mesh::TriMesh;
use std::sync::OnceLock;

/// A regular grid of samples: `dims[k]` samples along axis `k`, sample `(i, j, l)` at
/// `origin + (i, j, l) · spacing`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GridSpec {
    /// Samples per axis (at least 2 each for any cell).
    pub dims: [usize; 3],
    /// World position of sample (0, 0, 0).
    pub origin: [f64; 3],
    /// Distance between neighbouring samples per axis.
    pub spacing: [f64; 3],
}

impl GridSpec {
    /// World position of sample `(i, j, l)`.
    pub fn point(&self, i: usize, j: usize, l: usize) -> [f64; 3] {
        let idx = [i, j, l];
        [0, 1, 2].map(|k| self.origin[k] + idx[k] as f64 * self.spacing[k])
    }
}

/// Cube corner `c` is at offset `(c & 1, (c >> 1) & 1, (c >> 2) & 1)`.
const fn corner_offset(c: usize) -> [usize; 3] {
    [c & 1, (c >> 1) & 1, (c >> 2) & 1]
}

/// The 12 edges as (low corner, axis): for each axis, the four corners without that axis' bit.
fn edges() -> [(usize, usize); 12] {
    let mut e = [(0, 0); 12];
    let mut k = 0;
    for axis in 0..3 {
        for c in 0..8 {
            if c & (1 << axis) == 0 {
                e[k] = (c, axis);
                k += 1;
            }
        }
    }
    e
}

fn edge_between(a: usize, b: usize) -> usize {
    let (lo, hi) = (a.min(b), a.max(b));
    let axis = (hi ^ lo).trailing_zeros() as usize;
    edges().iter().position(|&e| e == (lo, axis)).expect("corners of one cube edge")
}

/// One polygon of a case: its vertices (edge indices, in order) and how it is cut into
/// triangles: a fan from vertex `apex`, or (`None`) a fan around a new vertex at its centroid.
#[derive(Clone, Debug)]
struct Polygon {
    edges: Vec<u8>,
    apex: Option<usize>,
}

/// Whether cube edges `a` and `b` lie on a common face of the cube.
fn share_face(a: usize, b: usize) -> bool {
    let ((ca, aa), (cb, ab)) = (edges()[a], edges()[b]);
    (0..3).any(|k| k != aa && k != ab && (ca >> k) & 1 == (cb >> k) & 1)
}

/// Per case (bitmask of inside corners), its polygons.
///
/// A fan diagonal must not join two vertices on one face of the cube: the cell across that
/// face (an ambiguous face, with four crossed edges) could join the same two vertices, and the
/// edge would then belong to four triangles. A diagonal between edges with no common face
/// belongs to no other cell. So a polygon is fanned from a vertex all of whose diagonals are of
/// that kind, and a polygon without such a vertex gets a centre vertex of its own.
fn case_table() -> &'static [Vec<Polygon>; 256] {
    static TABLE: OnceLock<[Vec<Polygon>; 256]> = OnceLock::new();
    TABLE.get_or_init(|| {
        // The six faces, corners counter-clockwise seen from outside the cube.
        let mut faces = Vec::new();
        for axis in 0..3 {
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            for side in 0..2 {
                let mut q: Vec<usize> = [(0, 0), (1, 0), (1, 1), (0, 1)].iter().map(|&(a, b)| (side << axis) | (a << u) | (b << v)).collect();
                // (u, v, axis) is right-handed, so this order faces +axis: right for side 1.
                if side == 0 {
                    q.reverse();
                }
                faces.push([q[0], q[1], q[2], q[3]]);
            }
        }
        let polygons = |mask: usize| -> Vec<Vec<usize>> {
            let inside = |c: usize| mask & (1 << c) != 0;
            let mut next = [usize::MAX; 12];
            for q in &faces {
                for i in 0..4 {
                    if inside(q[i]) && !inside(q[(i + 1) % 4]) {
                        let leave = edge_between(q[i], q[(i + 1) % 4]);
                        let mut j = i;
                        while inside(q[j]) {
                            j = (j + 3) % 4;
                        }
                        next[leave] = edge_between(q[j], q[(j + 1) % 4]);
                    }
                }
            }
            let mut used = [false; 12];
            let mut out = Vec::new();
            for start in 0..12 {
                if next[start] == usize::MAX || used[start] {
                    continue;
                }
                let mut poly = Vec::new();
                let mut e = start;
                while !used[e] {
                    used[e] = true;
                    poly.push(e);
                    e = next[e];
                }
                out.push(poly);
            }
            out
        };
        // Orientation: with only corner 0 inside, the triangle must face away from it.
        let mid = |e: usize| {
            let (c, axis) = edges()[e];
            let mut p = corner_offset(c).map(|v| v as f64);
            p[axis] += 0.5;
            glam::DVec3::from(p)
        };
        let p = &polygons(1)[0];
        let n = (mid(p[1]) - mid(p[0])).cross(mid(p[2]) - mid(p[0]));
        let flip = n.dot(glam::DVec3::ONE) < 0.0;
        std::array::from_fn(|mask| {
            polygons(mask)
                .into_iter()
                .map(|mut poly| {
                    if flip {
                        poly.reverse();
                    }
                    let m = poly.len();
                    let apex = (0..m).find(|&k| (2..m - 1).all(|d| !share_face(poly[k], poly[(k + d) % m])));
                    Polygon { edges: poly.iter().map(|&e| e as u8).collect(), apex }
                })
                .collect()
        })
    })
}

/// Extracts the surface `value = level` of the grid `grid`. `plane(l)` returns the values of
/// z-plane `l`, `dims[0] · dims[1]` of them with x fastest; it is called once per plane, in
/// order. `progress(done, total)` is called after each slab of cells. A grid with fewer than two
/// samples along an axis has no cells and gives an empty mesh.
///
/// # Panics
/// If `plane` returns a vector of the wrong length.
pub fn marching_cubes(grid: &GridSpec, level: f32, mut plane: impl FnMut(usize) -> Vec<f32>, progress: &mut dyn FnMut(usize, usize)) -> TriMesh {
    let [nx, ny, nz] = grid.dims;
    let mut mesh = TriMesh::default();
    if nx < 2 || ny < 2 || nz < 2 {
        return mesh;
    }
    let table = case_table();
    let edge_list = edges();
    const NONE: u32 = u32::MAX;
    // Vertex ids of the edges already cut: x- and y-edges of the slab's lower and upper
    // planes, z-edges of the slab.
    let (mut ex_lo, mut ey_lo) = (vec![NONE; (nx - 1) * ny], vec![NONE; nx * (ny - 1)]);
    let (mut ex_hi, mut ey_hi) = (ex_lo.clone(), ey_lo.clone());
    let mut ez = vec![NONE; nx * ny];
    let take = |l: usize, plane: &mut dyn FnMut(usize) -> Vec<f32>| {
        let v = plane(l);
        assert_eq!(v.len(), nx * ny, "plane {l} has {} values, the grid {}x{}", v.len(), nx, ny);
        v
    };
    let mut lo = take(0, &mut plane);
    for z in 0..nz - 1 {
        let hi = take(z + 1, &mut plane);
        for y in 0..ny - 1 {
            for x in 0..nx - 1 {
                let value = |c: usize| {
                    let o = corner_offset(c);
                    let p = if o[2] == 0 { &lo } else { &hi };
                    p[(y + o[1]) * nx + x + o[0]]
                };
                let vals: [f32; 8] = std::array::from_fn(value);
                let mask = (0..8).fold(0usize, |m, c| if vals[c] >= level { m | (1 << c) } else { m });
                if mask == 0 || mask == 255 {
                    continue;
                }
                for poly in &table[mask] {
                    let ids: Vec<u32> = poly
                        .edges
                        .iter()
                        .map(|&e| {
                            let (c, axis) = edge_list[e as usize];
                            let o = corner_offset(c);
                            let (gx, gy) = (x + o[0], y + o[1]);
                            let slot = match axis {
                                0 => &mut (if o[2] == 0 { &mut ex_lo } else { &mut ex_hi })[gy * (nx - 1) + gx],
                                1 => &mut (if o[2] == 0 { &mut ey_lo } else { &mut ey_hi })[gy * nx + gx],
                                _ => &mut ez[gy * nx + gx],
                            };
                            if *slot == NONE {
                                let (a, b) = (vals[c], vals[c | (1 << axis)]);
                                let t = ((level - a) / (b - a)) as f64;
                                let t = if t.is_finite() { t.clamp(0.0, 1.0) } else { 0.5 };
                                let mut p = grid.point(gx, gy, z + o[2]);
                                p[axis] += t * grid.spacing[axis];
                                *slot = mesh.positions.len() as u32;
                                mesh.positions.push(p.map(|v| v as f32));
                            }
                            *slot
                        })
                        .collect();
                    let m = ids.len();
                    match poly.apex {
                        Some(k) => {
                            for d in 1..m - 1 {
                                mesh.triangles.push([ids[k], ids[(k + d) % m], ids[(k + d + 1) % m]]);
                            }
                        }
                        None => {
                            let centre = ids.iter().fold([0.0f64; 3], |acc, &i| {
                                let p = mesh.positions[i as usize];
                                [0, 1, 2].map(|k| acc[k] + p[k] as f64 / m as f64)
                            });
                            let c = mesh.positions.len() as u32;
                            mesh.positions.push(centre.map(|v| v as f32));
                            for k in 0..m {
                                mesh.triangles.push([ids[k], ids[(k + 1) % m], c]);
                            }
                        }
                    }
                }
            }
        }
        std::mem::swap(&mut ex_lo, &mut ex_hi);
        std::mem::swap(&mut ey_lo, &mut ey_hi);
        ex_hi.fill(NONE);
        ey_hi.fill(NONE);
        ez.fill(NONE);
        lo = hi;
        progress(z + 1, nz - 1);
    }
    mesh
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;
    use std::f64::consts::PI;

    fn sample(grid: &GridSpec, f: impl Fn([f64; 3]) -> f32) -> impl FnMut(usize) -> Vec<f32> {
        let g = *grid;
        move |z| (0..g.dims[1]).flat_map(|y| (0..g.dims[0]).map(move |x| (x, y))).map(|(x, y)| f(g.point(x, y, z))).collect()
    }

    #[test]
    fn every_case_is_closed_and_oriented() {
        let t = case_table();
        assert!(t[0].is_empty() && t[255].is_empty());
        for (m, polys) in t.iter().enumerate() {
            assert!(!polys.is_empty() || m == 0 || m == 255, "case {m}");
            // Every crossed edge is a vertex of exactly one polygon.
            let crossed = edges().iter().filter(|(c, a)| ((m >> c) & 1) != ((m >> (c | (1 << a))) & 1)).count();
            assert_eq!(polys.iter().map(|p| p.edges.len()).sum::<usize>(), crossed, "case {m}");
        }
        // The single-corner case: one triangle.
        assert_eq!(t[1].len(), 1);
        assert_eq!(t[1][0].edges.len(), 3);
    }

    #[test]
    fn sphere_area_and_volume_within_one_percent_at_256() {
        let r = 0.35;
        let grid = GridSpec { dims: [257; 3], origin: [0.0; 3], spacing: [1.0 / 256.0; 3] };
        let f = |p: [f64; 3]| (r - ((p[0] - 0.5).powi(2) + (p[1] - 0.5).powi(2) + (p[2] - 0.5).powi(2)).sqrt()) as f32;
        let mut slabs = 0;
        let m = marching_cubes(&grid, 0.0, sample(&grid, f), &mut |d, t| {
            assert_eq!(t, 256);
            slabs = d;
        });
        assert_eq!(slabs, 256);
        let (area, volume) = (m.area(), m.signed_volume());
        let (a0, v0) = (4.0 * PI * r * r, 4.0 / 3.0 * PI * r * r * r);
        assert!((area / a0 - 1.0).abs() < 0.01, "area {area} vs {a0}");
        assert!((volume / v0 - 1.0).abs() < 0.01, "volume {volume} vs {v0}");
        // Every vertex on the sphere to within a small fraction of a cell.
        let worst = m.positions.iter().map(|p| (p.iter().map(|v| (*v as f64 - 0.5).powi(2)).sum::<f64>().sqrt() - r).abs()).fold(0.0, f64::max);
        assert!(worst < 0.1 / 256.0, "worst radial error {worst}");
        // Outward normals.
        for k in (0..m.triangles.len()).step_by(97) {
            let c = m.corners(k).iter().copied().sum::<glam::DVec3>() / 3.0 - glam::DVec3::splat(0.5);
            assert!(m.triangle_normal(k).dot(c) > 0.0);
        }
    }

    /// A random field inside a border of outside samples: the surface is closed and
    /// consistently oriented (every directed edge is matched by its reverse exactly once), the
    /// ambiguous face and cell cases included.
    #[test]
    fn random_field_gives_a_closed_oriented_surface() {
        let n = 14;
        let grid = GridSpec { dims: [n; 3], origin: [0.0; 3], spacing: [1.0; 3] };
        let hash = |k: u64| {
            let mut z = k.wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ 0x1234_5678;
            z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
            ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
        };
        let f = |p: [f64; 3]| {
            let i = p.map(|v| v as usize);
            if i.iter().any(|&v| v == 0 || v == n - 1) {
                return -1.0;
            }
            hash((i[0] + n * (i[1] + n * i[2])) as u64) - 0.5
        };
        let m = marching_cubes(&grid, 0.0, sample(&grid, f), &mut |_, _| {});
        assert!(m.triangles.len() > 1000);
        let mut directed: HashMap<(u32, u32), u32> = HashMap::new();
        for t in &m.triangles {
            assert!(t[0] != t[1] && t[1] != t[2] && t[0] != t[2]);
            for k in 0..3 {
                *directed.entry((t[k], t[(k + 1) % 3])).or_default() += 1;
            }
        }
        for (&(a, b), &count) in &directed {
            assert_eq!(count, 1, "edge {a}->{b} used {count} times");
            assert_eq!(directed.get(&(b, a)), Some(&1), "edge {a}->{b} has no reverse");
        }
        assert!(m.signed_volume() > 0.0);
    }

    #[test]
    fn tiny_and_empty_grids() {
        let g = GridSpec { dims: [1, 5, 5], origin: [0.0; 3], spacing: [1.0; 3] };
        assert!(marching_cubes(&g, 0.0, |_| vec![1.0; 5], &mut |_, _| {}).triangles.is_empty());
        let g = GridSpec { dims: [4; 3], origin: [0.0; 3], spacing: [1.0; 3] };
        assert!(marching_cubes(&g, 0.5, |_| vec![0.0; 16], &mut |_, _| {}).triangles.is_empty());
        assert!(marching_cubes(&g, 0.5, |_| vec![f32::NAN; 16], &mut |_, _| {}).triangles.is_empty());
    }
}
