// Noise floor of a dataset's test images: re-render test views with another seed and compare
// in display space (sRGB, [0,1], composited on black as the PNG's premultiplied RGB).
use pathtracer::accel::AccelParams;
use pathtracer::render::{RenderSettings, Renderer};
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let (scene, ds, nviews) = (&a[1], &a[2], a[3].parse::<usize>().unwrap());
    let d = dataset::Dataset::load(std::path::Path::new(ds)).unwrap();
    let s = pathtracer::import::load_gltf(std::path::Path::new(scene), &Default::default()).unwrap();
    let r = Renderer::new(s, &AccelParams::medium_build()).unwrap();
    let set = RenderSettings { spp: 128, max_bounces: 8, seed: 12345, environment: [0.1; 3], transparent_background: true, environment_map: None };
    let disp = |x: f32| dataset::linear_to_srgb(x.max(0.0)).min(1.0) as f64;
    let mut tot = 0.0;
    for (k, f) in d.test.iter().take(nviews).enumerate() {
        let o = r.render_view(&f.camera, 100 + k as u32, &set);
        let b = r.render_view(&f.camera, 200 + k as u32, &set);
        let n = o.color.data.len() / 4;
        let mut mse = 0.0;
        for p in 0..n { for c in 0..3 { let (x, y) = (o.color.data[4*p+c], b.color.data[4*p+c]); mse += (disp(x) - disp(y)).powi(2); } }
        mse /= (3 * n) as f64 * 2.0;
        tot += mse;
        println!("{}: sigma^2 {:.3e} -> ceiling {:.2} dB", f.name, mse, -10.0 * mse.log10());
    }
    let m = tot / nviews as f64;
    println!("mean sigma^2 {:.3e} -> ceiling {:.2} dB", m, -10.0 * m.log10());
}
