//! An end-to-end check of the autodiff core on the shape of computation the
//! renderer runs: many samples, each reading a lookup table (gather), a chain
//! of transcendental functions, a segmented sum into "pixels", and an L1 loss
//! against a target. Prints the loss, the gradients' size, the time per
//! forward + backward in f32, and the finite-difference check in f64.
//!
//! `cargo run --release -p autodiff --example gradient_check`

use std::time::Instant;

use autodiff::gradcheck::{Input, gradcheck_sampled, uniform};
use autodiff::{Real, Tape, Var};

const PIXELS: usize = 4096;
const SAMPLES_PER_PIXEL: usize = 16;
const TEXELS: usize = 64 * 32;

/// Per sample: a lobe weight exp(-(cos - 1) / roughness^2) times a texel
/// value, summed per pixel, compared with the target by L1.
fn program<'t, T: Real>(tape: &'t Tape<T>, table: Var<'t, T>, roughness: Var<'t, T>, data: &Data<T>) -> Var<'t, T> {
    let cos = tape.constant(&data.cos_theta);
    let texel = tape.constant(&data.texel);
    let pixel = tape.constant(&data.pixel);
    let alpha2 = roughness * roughness;
    let lobe = ((cos - T::one()) / alpha2).exp() * cos.max_scalar(T::zero());
    let radiance = table.gather(texel) * lobe;
    let image = radiance.segmented_sum(pixel, data.target.len()) * T::c(1.0 / SAMPLES_PER_PIXEL as f64);
    (image - tape.constant(&data.target)).abs().mean()
}

struct Data<T> {
    cos_theta: Vec<T>,
    texel: Vec<T>,
    pixel: Vec<T>,
    target: Vec<T>,
}

fn data<T: Real>(pixels: usize) -> Data<T> {
    let n = pixels * SAMPLES_PER_PIXEL;
    let c = |v: Vec<f64>| v.into_iter().map(T::c).collect::<Vec<T>>();
    Data {
        cos_theta: c(uniform(n, 0.2, 1.0, 1)),
        texel: c(uniform(n, 0.0, TEXELS as f64, 2).into_iter().map(f64::floor).collect()),
        pixel: c((0..n).map(|i| (i / SAMPLES_PER_PIXEL) as f64).collect()),
        target: c(uniform(pixels, 0.0, 0.5, 3)),
    }
}

fn main() {
    // Speed, in f32.
    let d32 = data::<f32>(PIXELS);
    let tape = Tape::<f32>::new();
    let table = tape
        .leaf(
            &uniform(TEXELS, 0.0, 2.0, 4)
                .iter()
                .map(|&v| v as f32)
                .collect::<Vec<_>>(),
        )
        .id();
    let roughness = tape.leaf(&[0.4]).id();
    let mark = tape.mark();
    let mut best = f64::INFINITY;
    for _ in 0..20 {
        let start = Instant::now();
        tape.reset_to(mark);
        let loss = program(&tape, tape.var(table), tape.var(roughness), &d32);
        tape.backward(loss);
        best = best.min(start.elapsed().as_secs_f64());
    }
    let loss = program(&tape, tape.var(table), tape.var(roughness), &d32);
    tape.backward(loss);
    println!(
        "{} samples into {PIXELS} pixels: loss {:.6}, d loss / d roughness {:.6}, {} texel gradients, {} nodes",
        PIXELS * SAMPLES_PER_PIXEL,
        tape.value(loss)[0],
        tape.grad(tape.var(roughness))[0],
        tape.grad(tape.var(table)).len(),
        tape.len()
    );
    println!("forward + backward: {:.3} ms (best of 20, f32)", best * 1e3);

    // Correctness, in f64, by central differences on a smaller problem.
    let d64 = data::<f64>(256);
    let inputs = [Input::Var(uniform(TEXELS, 0.0, 2.0, 4)), Input::Var(vec![0.4])];
    let report = gradcheck_sampled(&inputs, 24, |t, v| program(t, v[0], v[1], &d64));
    println!("gradient check (f64): {report}");
    assert!(report.worst_rel_error < 1e-6, "gradient check failed: {report}");
}
