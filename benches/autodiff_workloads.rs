//! The three shared autodiff workloads (shared/bench/WORKLOADS.md): the tape
//! against a hand-fused loop measured in the same run, forward and
//! forward + backward, on 1 and 2 threads. One JSON object per line on
//! stdout; progress and check failures on stderr.
//!
//! `cargo bench --bench autodiff_workloads [-- quick]` (`quick`: sizes up to 2^20 only).

use std::time::{Duration, Instant};

use autodiff::{Real, Tape};
use rayon::prelude::*;
use serde_json::{Value, json};

/// Times `f` warm: one call excluded, then repeated for about half a second.
fn time<R>(mut f: impl FnMut() -> R) -> ((f64, f64, usize), R) {
    let mut out = f();
    let mut times = Vec::new();
    let start = Instant::now();
    while times.len() < 5 || (times.len() < 25 && start.elapsed() < Duration::from_millis(500)) {
        let t = Instant::now();
        out = f();
        times.push(t.elapsed().as_secs_f64());
    }
    times.sort_by(f64::total_cmp);
    ((times[times.len() / 2], times[0], times.len()), out)
}

/// What was measured: workload, implementation, mode, and the size's field name and value.
type Case<'a> = (&'a str, &'a str, &'a str, (&'a str, usize));

fn report((bench, imp, mode, size): Case, threads: usize, timing: (f64, f64, usize), (check, ok): (Value, bool)) {
    let mut line = json!({
        "bench": bench, "impl": imp, "mode": mode, "threads": threads,
        "median_s": timing.0, "min_s": timing.1, "runs": timing.2, "check": check, "check_ok": ok,
    });
    line[size.0] = json!(size.1);
    println!("{line}");
    if !ok {
        eprintln!("CHECK FAILED: {line}");
    }
}

fn close(got: f64, want: f64, rel: f64) -> bool {
    (got - want).abs() <= rel * want.abs()
}

// ---------------------------------------------------------------- chain

fn chain_input(n: usize) -> Vec<f32> {
    (0..n).map(|i| (i as f64 * 0.001).sin() as f32).collect()
}

/// The chain of WORKLOADS.md on the tape: returns y (and fills the gradient).
fn chain_tape(tape: &Tape<f32>, x: autodiff::Var<'_, f32>, backward: bool) -> (f64, Option<Vec<f32>>) {
    let a = x * x + 1.0;
    let b = a.sqrt();
    let c = (-b).exp();
    let d = c * x + a;
    // max(d, 1.1) and min(p, 0.5) with WORKLOADS.md's derivative convention
    // at the kink (0 on a tie, which f32 rounding makes possible): clamps.
    let e = d.clamp(1.1, f32::INFINITY);
    let g = e.ln();
    let h = g / (a + 1.0);
    let k = (h * b).sin();
    let m = k * c - x;
    let p = m * m * 0.5 + h;
    let q = p.clamp(f32::NEG_INFINITY, 0.5);
    let y = (q * e).sum();
    if backward {
        tape.backward(y);
        (tape.value(y)[0] as f64, Some(tape.grad(x).to_vec()))
    } else {
        (tape.value(y)[0] as f64, None)
    }
}

/// One element of the chain, forward and (optionally) its hand-written reverse sweep.
#[inline(always)]
fn chain_fused_element(x: f32) -> (f32, f32) {
    let a = x * x + 1.0;
    let b = a.sqrt();
    let c = (-b).exp_v();
    let d = c * x + a;
    let e = if d > 1.1 { d } else { 1.1 };
    let g = e.ln_v();
    let t4 = a + 1.0;
    let h = g / t4;
    let t5 = h * b;
    let (k, cos_t5) = t5.sin_cos_v();
    let m = k * c - x;
    let p = m * m * 0.5 + h;
    let q = if p < 0.5 { p } else { 0.5 };
    let r = q * e;
    let dq = e;
    let mut de = q;
    let dp = if p < 0.5 { dq } else { 0.0 };
    let mut dh = dp;
    let dm = m * dp;
    let mut dx = -dm;
    let dk = c * dm;
    let mut dc = k * dm;
    let dt5 = cos_t5 * dk;
    dh += b * dt5;
    let mut db = h * dt5;
    let dg = dh / t4;
    let mut da = -dh * h / t4;
    de += dg / e;
    let dd = if d > 1.1 { de } else { 0.0 };
    da += dd;
    dc += x * dd;
    dx += c * dd;
    db -= c * dc;
    da += db / (2.0 * b);
    dx += 2.0 * x * da;
    (r, dx)
}

const PAR_BLOCK: usize = 1 << 14;

/// Lanes per block: a fixed-size inner loop the compiler vectorises whole.
const LANES: usize = 16;

fn chain_fused_block(x: &[f32], grad: Option<&mut [f32]>) -> f64 {
    let mut acc = [0f32; LANES];
    let xs = x.chunks_exact(LANES);
    let rest = xs.remainder();
    match grad {
        None => {
            for c in xs {
                let c: &[f32; LANES] = c.try_into().expect("a full block");
                for l in 0..LANES {
                    acc[l] += chain_fused_element(c[l]).0;
                }
            }
            for &x in rest {
                acc[0] += chain_fused_element(x).0;
            }
        }
        Some(grad) => {
            let (gs, grest) = grad.split_at_mut(x.len() - rest.len());
            for (c, g) in xs.zip(gs.chunks_exact_mut(LANES)) {
                let c: &[f32; LANES] = c.try_into().expect("a full block");
                let g: &mut [f32; LANES] = g.try_into().expect("a full block");
                for l in 0..LANES {
                    let (r, dx) = chain_fused_element(c[l]);
                    acc[l] += r;
                    g[l] = dx;
                }
            }
            for (&x, g) in rest.iter().zip(grest) {
                let (r, dx) = chain_fused_element(x);
                acc[0] += r;
                *g = dx;
            }
        }
    }
    acc.iter().map(|&v| v as f64).sum()
}

fn chain_fused(x: &[f32], grad: Option<&mut [f32]>) -> f64 {
    match grad {
        None => x.par_chunks(PAR_BLOCK).map(|xs| chain_fused_block(xs, None)).sum(),
        Some(grad) => x
            .par_chunks(PAR_BLOCK)
            .zip(grad.par_chunks_mut(PAR_BLOCK))
            .map(|(xs, gs)| chain_fused_block(xs, Some(gs)))
            .sum(),
    }
}

fn chain_reference(n: usize) -> (f64, f64) {
    match n {
        65536 => (37105.49009676288, 9504.599037277898),
        1048576 => (586735.1099786133, 104440.25467061649),
        4194304 => (2345895.1048251195, 418972.6637071554),
        _ => unreachable!("no reference for N = {n}"),
    }
}

fn chain_check(n: usize, y: f64, grad: Option<&[f32]>) -> (Value, bool) {
    let (y_ref, sum_ref) = chain_reference(n);
    let mut ok = close(y, y_ref, 2e-6);
    let mut check = json!({ "y": y });
    if let Some(g) = grad {
        let sum: f64 = g.iter().map(|&v| v as f64).sum();
        check["sum_grad"] = json!(sum);
        check["grad_0"] = json!(g[0]);
        check["grad_1000"] = json!(g[1000]);
        ok &= close(sum, sum_ref, 2e-6)
            && close(g[0] as f64, -0.019277167060735637, 1e-5)
            && close(g[1000] as f64, 0.9034789869262752, 1e-5);
    }
    (check, ok)
}

fn elementwise_chain(n: usize, threads: usize) {
    let x = chain_input(n);
    for backward in [false, true] {
        let mode = if backward { "fwd_bwd" } else { "fwd" };
        let tape = Tape::<f32>::new();
        let xid = tape.leaf(&x).id();
        let mark = tape.mark();
        let (timing, (y, grad)) = time(|| {
            tape.reset_to(mark);
            chain_tape(&tape, tape.var(xid), backward)
        });
        report(
            ("elementwise_chain", "tape", mode, ("n", n)),
            threads,
            timing,
            chain_check(n, y, grad.as_deref()),
        );

        let mut grad = vec![0f32; n];
        let (timing, y) = time(|| chain_fused(&x, backward.then_some(&mut grad[..])));
        report(
            ("elementwise_chain", "fused", mode, ("n", n)),
            threads,
            timing,
            chain_check(n, y, backward.then_some(&grad[..])),
        );
    }
}

// ---------------------------------------------------------------- gather / scatter

struct GatherData {
    table: Vec<f32>,
    texel: Vec<f32>,
    weight: Vec<f32>,
    texel_u32: Vec<u32>,
}

fn gather_data(m: usize) -> GatherData {
    let table = (0..256 * 128 * 3)
        .map(|k| (0.5 + 0.5 * (k as f64 * 0.01).sin()) as f32)
        .collect();
    let mut s: u32 = 1;
    let texel_u32: Vec<u32> = (0..m)
        .map(|_| {
            s = s.wrapping_mul(1664525).wrapping_add(1013904223);
            s >> 17
        })
        .collect();
    assert_eq!(
        &texel_u32[..5],
        &[7748, 12100, 16523, 23097, 1656],
        "the LCG of WORKLOADS.md"
    );
    let texel = texel_u32.iter().map(|&t| t as f32).collect();
    let weight = (0..m).map(|j| (0.5 + 0.25 * (j as f64 * 0.01).sin()) as f32).collect();
    GatherData {
        table,
        texel,
        weight,
        texel_u32,
    }
}

fn gather_check(y: f64, grad: Option<&[f32]>) -> (Value, bool) {
    let mut ok = close(y, 787378.542515006, 2e-6);
    let mut check = json!({ "y": y });
    if let Some(g) = grad {
        let sum: f64 = g.iter().map(|&v| v as f64).sum();
        let mod7: f64 = g.iter().enumerate().map(|(k, &v)| v as f64 * (k % 7) as f64).sum();
        check["sum_dT"] = json!(sum);
        check["sum_dT_mod7"] = json!(mod7);
        ok &= close(sum, 1572891.2867366374, 2e-6) && close(mod7, 4719887.075535595, 2e-6);
    }
    (check, ok)
}

fn gather_fused(d: &GatherData, grad: Option<&mut [f32]>) -> f64 {
    let t = &d.table;
    let y = d
        .texel_u32
        .par_chunks(PAR_BLOCK)
        .zip(d.weight.par_chunks(PAR_BLOCK))
        .map(|(ts, ws)| {
            let mut acc = 0f32;
            for (&j, &w) in ts.iter().zip(ws) {
                let k = 3 * j as usize;
                acc += w * (t[k] + t[k + 1] + t[k + 2]);
            }
            acc as f64
        })
        .sum();
    if let Some(grad) = grad {
        // Per-thread private gradients, summed: the practical fused scatter.
        let parts: Vec<Vec<f32>> = d
            .texel_u32
            .par_chunks(d.texel_u32.len().div_ceil(rayon::current_num_threads()))
            .zip(
                d.weight
                    .par_chunks(d.weight.len().div_ceil(rayon::current_num_threads())),
            )
            .map(|(ts, ws)| {
                let mut g = vec![0f32; t.len()];
                for (&j, &w) in ts.iter().zip(ws) {
                    let k = 3 * j as usize;
                    g[k] += w;
                    g[k + 1] += w;
                    g[k + 2] += w;
                }
                g
            })
            .collect();
        grad.fill(0.0);
        for p in parts {
            for (g, v) in grad.iter_mut().zip(p) {
                *g += v;
            }
        }
    }
    y
}

fn gather_scatter(m: usize, threads: usize) {
    let d = gather_data(m);
    for backward in [false, true] {
        let mode = if backward { "fwd_bwd" } else { "fwd" };
        let tape = Tape::<f32>::new();
        let table = tape.leaf(&d.table).id();
        let texel = tape.constant(&d.texel).id();
        let weight = tape.constant(&d.weight).id();
        let mark = tape.mark();
        let (timing, (y, grad)) = time(|| {
            tape.reset_to(mark);
            let (table, texel, weight) = (tape.var(table), tape.var(texel), tape.var(weight));
            let rgb = table.gather_channel(texel, 3, 0)
                + table.gather_channel(texel, 3, 1)
                + table.gather_channel(texel, 3, 2);
            let y = (rgb * weight).sum();
            if backward {
                tape.backward(y);
            }
            (tape.value(y)[0] as f64, backward.then(|| tape.grad(table).to_vec()))
        });
        report(
            ("gather_scatter", "tape", mode, ("m", m)),
            threads,
            timing,
            gather_check(y, grad.as_deref()),
        );

        let mut grad = vec![0f32; d.table.len()];
        let (timing, y) = time(|| gather_fused(&d, backward.then_some(&mut grad[..])));
        report(
            ("gather_scatter", "fused", mode, ("m", m)),
            threads,
            timing,
            gather_check(y, backward.then_some(&grad[..])),
        );
    }
}

// ---------------------------------------------------------------- small ops

const K: usize = 10_000;

/// Checksums, and the time per op of a run that took `median_s`.
fn small_check(y: f64, sum_grad: Option<f64>, median_s: f64) -> (Value, bool) {
    let mut ok = close(y, 2.0713811511571367, 1e-5);
    let mut check = json!({ "y": y, "per_op_us": median_s / K as f64 * 1e6 });
    if let Some(s) = sum_grad {
        check["sum_grad"] = json!(s);
        ok &= close(s, 10.78087952077259, 1e-5);
    }
    (check, ok)
}

fn small_fused(x: &[f32; 8], history: &mut Vec<[f32; 8]>, backward: bool) -> (f64, f64) {
    history.clear();
    let mut v = *x;
    for i in 0..K {
        history.push(v);
        for (l, e) in v.iter_mut().enumerate() {
            *e = match i % 4 {
                0 => *e * 0.5,
                1 => *e + x[l],
                2 => e.sin_cos_v().0,
                _ => *e - 0.25,
            };
        }
    }
    let y: f64 = v.iter().map(|&e| e as f64).sum();
    if !backward {
        return (y, 0.0);
    }
    let mut gv = [1f32; 8];
    let mut gx = [0f32; 8];
    for i in (0..K).rev() {
        let before = &history[i];
        for l in 0..8 {
            match i % 4 {
                0 => gv[l] *= 0.5,
                1 => gx[l] += gv[l],
                2 => gv[l] *= before[l].sin_cos_v().1,
                _ => {}
            }
        }
    }
    for l in 0..8 {
        gx[l] += gv[l];
    }
    (y, gx.iter().map(|&g| g as f64).sum())
}

fn small_ops_overhead(threads: usize) {
    let x: [f32; 8] = std::array::from_fn(|l| (0.1 * (l + 1) as f64) as f32);
    for backward in [false, true] {
        let mode = if backward { "fwd_bwd" } else { "fwd" };
        let tape = Tape::<f32>::new();
        let xid = tape.leaf(&x).id();
        let mark = tape.mark();
        let (timing, (y, s)) = time(|| {
            tape.reset_to(mark);
            let x = tape.var(xid);
            let mut v = x;
            for i in 0..K {
                v = match i % 4 {
                    0 => v * 0.5,
                    1 => v + x,
                    2 => v.sin(),
                    _ => v - 0.25,
                };
            }
            let y = v.sum();
            if backward {
                tape.backward(y);
            }
            let s = backward.then(|| tape.grad(x).iter().map(|&g| g as f64).sum::<f64>());
            (tape.value(y)[0] as f64, s)
        });
        report(
            ("small_ops_overhead", "tape", mode, ("k", K)),
            threads,
            timing,
            small_check(y, s, timing.0),
        );

        let mut history = Vec::with_capacity(K);
        let (timing, (y, s)) = time(|| small_fused(&x, &mut history, backward));
        report(
            ("small_ops_overhead", "fused", mode, ("k", K)),
            threads,
            timing,
            small_check(y, backward.then_some(s), timing.0),
        );
    }
}

fn main() {
    let quick = std::env::args().any(|a| a == "quick");
    let sizes: &[usize] = if quick {
        &[1 << 16, 1 << 20]
    } else {
        &[1 << 16, 1 << 20, 1 << 22]
    };
    for threads in [1, 2] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("a thread pool");
        pool.install(|| {
            for &n in sizes {
                eprintln!("elementwise_chain n={n} threads={threads}");
                elementwise_chain(n, threads);
            }
            eprintln!("gather_scatter threads={threads}");
            gather_scatter(1 << 20, threads);
            eprintln!("small_ops_overhead threads={threads}");
            small_ops_overhead(threads);
        });
    }
}
