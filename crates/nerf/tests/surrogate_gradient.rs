//! The surrogate backward `sum(output · grad.detach())` gives the parameter gradients of the
//! full loss (network in burn → volume rendering and MSE in Rust): checked against central
//! finite differences on a tiny paper field.

use burn::module::Module;
use burn::tensor::Tensor;
use nerf::field::{NerfField, NerfFieldConfig};
use nerf::kernels::{param_vectors, seeded_init, tensor2, to_vec};
use nerf::encoding::frequency_encode;
use nerf::models::ops::{self, DensityActivation};
use nerf::sampling::{RaySamples, SampleMode, stratified};
use nerf::volrend;

struct Setup {
    samples: RaySamples,
    pos: Vec<f32>,
    dir: Vec<f32>,
    target: Vec<[f32; 3]>,
    bg: Vec<[f32; 3]>,
    cfg: NerfFieldConfig,
}

const ACT: DensityActivation = DensityActivation::Softplus;

fn outputs(s: &Setup, net: &NerfField, dev: &burn::tensor::Device) -> (Tensor<2>, Tensor<2>) {
    let n = s.samples.len();
    net.forward(tensor2(s.pos.clone(), n, s.cfg.pos_dims(), dev), tensor2(s.dir.clone(), n, s.cfg.dir_dims(), dev))
}

fn loss_of(s: &Setup, raw: &[f32], rgb: &[f32]) -> (f64, Vec<f32>, Vec<f32>) {
    let sigma: Vec<f32> = raw.iter().map(|x| ACT.forward(*x)).collect();
    let rgb3 = ops::rgb3(rgb);
    let sm = &s.samples;
    let comp = volrend::composite_forward(&volrend::CompositeInputs { offsets: &sm.offsets, sigma: &sigma, rgb: &rgb3, t_start: &sm.t_start, t_end: &sm.t_end, background: &s.bg });
    let n = (comp.rgb.len() * 3) as f64;
    let mut loss = 0.0;
    let mut g = Vec::new();
    for (c, t) in comp.rgb.iter().zip(&s.target) {
        let mut gg = [0.0f32; 3];
        for k in 0..3 {
            let e = (c[k] - t[k]) as f64;
            loss += e * e / n;
            gg[k] = (2.0 * e / n) as f32;
        }
        g.push(gg);
    }
    let zeros = vec![0.0; g.len()];
    let gr = volrend::composite_backward(&volrend::CompositeInputs { offsets: &sm.offsets, sigma: &sigma, rgb: &rgb3, t_start: &sm.t_start, t_end: &sm.t_end, background: &s.bg }, &comp, &volrend::OutputGrads { d_rgb: &g, d_opacity: &zeros, d_distance: &zeros, d_weights: None });
    let draw = gr.d_sigma.iter().zip(raw).map(|(d, x)| ACT.backward(*x, *d)).collect();
    (loss, draw, gr.d_rgb.into_iter().flatten().collect())
}

#[test]
fn surrogate_gradient_matches_finite_differences() {
    let train = nerf::backend::train_device();
    let plain = nerf::backend::inference_device();
    let cfg = NerfFieldConfig::new().with_pos_freqs(2).with_dir_freqs(1).with_width(8).with_depth(3).with_skip(2).with_color_width(8);
    let samples = stratified(&[1.0, 1.2], &[3.0, 3.5], 8, SampleMode::Random { seed: 3, step: 0 });
    let origins = [[0.0f32, 0.0, 2.0], [0.3, -0.2, 2.2]];
    let dirs = [[0.0f32, 0.0, -1.0], [-0.1, 0.1, -0.99]];
    let pts: Vec<[f32; 3]> = samples.positions(&origins, &dirs).into_iter().map(|p| p.map(|v| v * 0.5)).collect();
    let sd = ops::sample_dirs(&samples.ray_index, &dirs);
    let (pd, dd) = (cfg.pos_dims(), cfg.dir_dims());
    let mut pos = vec![0.0; pts.len() * pd];
    let mut dir = vec![0.0; pts.len() * dd];
    frequency_encode(&pts, cfg.pos_freqs, &mut pos);
    frequency_encode(&sd, cfg.dir_freqs, &mut dir);
    let s = Setup { samples, pos, dir, target: vec![[0.9, 0.2, 0.4], [0.1, 0.8, 0.3]], bg: vec![[1.0; 3]; 2], cfg: cfg.clone() };
    let net = seeded_init(cfg.init(&train), 11);

    // Surrogate gradient.
    let (raw_t, rgb_t) = outputs(&s, &net, &train);
    let n = s.samples.len();
    let (_, draw, drgb) = loss_of(&s, &to_vec(raw_t.clone()), &to_vec(rgb_t.clone()));
    let sur = (raw_t * tensor2(draw, n, 1, &train)).sum() + (rgb_t * tensor2(drgb, n, 3, &train)).sum();
    let grads = sur.backward();
    let analytic: Vec<Vec<f32>> = vec![
        to_vec(net.trunk.layers[0].weight.val().grad(&grads).unwrap()),
        to_vec(net.density.weight.val().grad(&grads).unwrap()),
        to_vec(net.color_out.bias.as_ref().unwrap().val().grad(&grads).unwrap()),
    ];
    // Indices of those tensors in visiting order.
    let params = param_vectors(&net);
    let idx_of = |v: &[f32]| params.iter().position(|p| p.len() == v.len()).unwrap();
    let which = [
        idx_of(&to_vec(net.trunk.layers[0].weight.val())),
        params.iter().position(|p| p == &to_vec(net.density.weight.val())).unwrap(),
        params.iter().position(|p| p == &to_vec(net.color_out.bias.as_ref().unwrap().val())).unwrap(),
    ];

    let full_loss = |values: &[Vec<f32>]| {
        let m = nerf::kernels::load_param_vectors(cfg.init(&plain), values).unwrap();
        let (r, c) = outputs(&s, &m.valid(), &plain);
        loss_of(&s, &to_vec(r), &to_vec(c)).0
    };
    let mut checked = 0;
    for (a, &pi) in analytic.iter().zip(&which) {
        for (j, g) in a.iter().enumerate().step_by(3) {
            let eps = 1e-2f32;
            let mut p = params.clone();
            p[pi][j] += eps;
            let lp = full_loss(&p);
            p[pi][j] -= 2.0 * eps;
            let lm = full_loss(&p);
            let fd = ((lp - lm) / (2.0 * eps as f64)) as f32;
            let tol = 2e-3 + 0.05 * fd.abs().max(g.abs());
            assert!((fd - g).abs() <= tol, "param {pi}[{j}]: surrogate {g} vs finite difference {fd}");
            checked += 1;
        }
    }
    assert!(checked > 10);
}
