use pathtracer::accel::AccelParams;
use pathtracer::dataset_render::{DatasetRenderConfig, Preset};
use pathtracer::render::{RenderSettings, Renderer};
fn main() {
    let path = std::path::Path::new("scenes/materials.gltf");
    let scene = pathtracer::import::load_gltf(path, &pathtracer::import::ImportOptions::default()).unwrap();
    let renderer = Renderer::new(scene, &AccelParams::medium_build()).unwrap();
    let quick = DatasetRenderConfig::preset(Preset::Quick);
    let rig = pathtracer::rig::build_rig(renderer.scene(), &quick.rig_config()).unwrap();
    let cam = rig.split(dataset::SplitKind::Train)[0];
    let s = 128.0 / cam.intrinsics.width as f64;
    let mut c = cam;
    c.intrinsics.width = 128;
    c.intrinsics.height = (cam.intrinsics.height as f64 * s).round() as u32;
    c.intrinsics.fl_x *= s; c.intrinsics.fl_y *= s; c.intrinsics.cx *= s; c.intrinsics.cy *= s;
    let spp: u32 = std::env::args().nth(1).unwrap().parse().unwrap();
    let runs: u32 = std::env::args().nth(2).unwrap().parse().unwrap();
    let settings = RenderSettings { spp, max_bounces: quick.max_bounces, seed: 7, environment: quick.environment, transparent_background: false, environment_map: None };
    let mut acc = vec![0f64; 128 * 128 * 3];
    for k in 0..runs {
        let out = renderer.render_view(&c, 100 + k, &settings);
        let img: Vec<f64> = out.color.data.chunks_exact(4).flat_map(|p| [p[0] as f64, p[1] as f64, p[2] as f64]).collect();
        let px = |y: usize, x: usize| [img[(y * 128 + x) * 3], img[(y * 128 + x) * 3 + 1], img[(y * 128 + x) * 3 + 2]];
        println!("run {k}: (69,102) {:?} (60,106) {:?} max {:.2}", px(69, 102), px(60, 106), img.iter().cloned().fold(0.0, f64::max));
        std::fs::write(format!("/tmp/ours_run{k}.f32"), img.iter().flat_map(|v| (*v as f32).to_le_bytes()).collect::<Vec<u8>>()).unwrap();
        for (a, b) in acc.iter_mut().zip(&img) { *a += b / runs as f64; }
    }
    let bytes: Vec<u8> = acc.iter().flat_map(|v| (*v as f32).to_le_bytes()).collect();
    std::fs::write("/tmp/ours_mean.f32", bytes).unwrap();
}
