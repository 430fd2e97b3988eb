//! The executor on programs large enough to span many tiles and threads:
//! values and gradients must not depend on how the work was cut.

use autodiff::gradcheck::{Input, gradcheck, gradcheck_sampled, uniform};
use autodiff::{Quat, Tape, Var, Vec3};

fn pool(threads: usize) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("a thread pool")
}

/// A per-sample chain with a broadcast parameter, a gather from a small
/// table and a segmented sum into a few "pixels", ending in a scalar loss.
fn program<'t>(tape: &'t Tape<f64>, x: Var<'t, f64>, theta: Var<'t, f64>, table: Var<'t, f64>) -> Var<'t, f64> {
    let n = x.len();
    let idx: Vec<f64> = (0..n).map(|i| ((i * 7919) % table.len()) as f64).collect();
    let seg: Vec<f64> = (0..n).map(|i| (i * 16 / n) as f64).collect();
    let a = x * x + 1.0;
    let b = (a.sqrt() * theta).sin() * (-x).exp();
    let c = table.gather(tape.constant(&idx)) * b + a.ln();
    let pixels = c.segmented_sum(tape.constant(&seg), 16) * (16.0 / n as f64);
    (pixels * pixels).sum() + c.huber(0.5).mean() * theta
}

fn run(threads: usize, n: usize) -> (f64, Vec<f64>, f64, Vec<f64>) {
    pool(threads).install(|| {
        let tape = Tape::<f64>::new();
        let x = tape.leaf(&uniform(n, -2.0, 2.0, 1));
        let theta = tape.leaf(&[0.7]);
        let table = tape.leaf(&uniform(37, 0.5, 1.5, 2));
        let loss = program(&tape, x, theta, table);
        tape.backward(loss);
        let value = tape.value(loss)[0];
        (
            value,
            tape.grad(x).to_vec(),
            tape.grad(theta)[0],
            tape.grad(table).to_vec(),
        )
    })
}

#[test]
fn large_program_gradients_match_finite_differences() {
    let n = 100_003; // many tiles, a ragged last one, parallel chunks
    let inputs = [
        Input::Var(uniform(n, -2.0, 2.0, 1)),
        Input::Var(vec![0.7]),
        Input::Var(uniform(37, 0.5, 1.5, 2)),
    ];
    let report = pool(2).install(|| gradcheck_sampled(&inputs, 6, |t, v| program(t, v[0], v[1], v[2])));
    assert!(report.worst_rel_error < 1e-6, "{report}");
}

#[test]
fn small_program_gradients_match_finite_differences() {
    // Small enough that the region keeps every value (no recomputation).
    let inputs = [
        Input::Var(uniform(40, -2.0, 2.0, 1)),
        Input::Var(vec![0.7]),
        Input::Var(uniform(37, 0.5, 1.5, 2)),
    ];
    let report = gradcheck(&inputs, |t, v| program(t, v[0], v[1], v[2]));
    assert!(report.worst_rel_error < 1e-6, "{report}");
}

#[test]
fn results_do_not_depend_on_the_thread_count() {
    let n = 150_000;
    let (v1, gx1, gt1, gtab1) = run(1, n);
    let (v2, gx2, gt2, gtab2) = run(2, n);
    assert_eq!(v1, v2);
    assert!(gx1 == gx2, "per-element gradients differ between 1 and 2 threads");
    // Accumulations run over a split that depends on the length only.
    assert_eq!(gt1, gt2);
    assert_eq!(gtab1, gtab2);
}

#[test]
fn values_inside_a_region_can_be_read_after_it_ran() {
    let tape = Tape::<f32>::new();
    let x = tape.leaf(
        &uniform(50_000, 0.0, 1.0, 3)
            .iter()
            .map(|&v| v as f32)
            .collect::<Vec<_>>(),
    );
    let inner = (x * 2.0).exp();
    let total = (inner + 1.0).sum();
    let t = tape.value(total)[0];
    // `inner` lived only in tiles; asking for it (or using it later) recomputes it.
    let inner_values = tape.value(inner).to_vec();
    let expect: f64 = inner_values.iter().map(|&v| v as f64 + 1.0).sum();
    assert!((t as f64 - expect).abs() < 1e-6 * expect);
    let later = (inner * x).sum();
    tape.backward(later);
    let g = tape.grad(x);
    let xs = tape.value(x);
    for i in [0, 777, 49_999] {
        let want = (2.0 * xs[i]).exp() * (1.0 + 2.0 * xs[i]);
        assert!((g[i] - want).abs() < 1e-5 * want, "{} vs {want}", g[i]);
    }
}

#[test]
fn several_backward_passes_from_one_forward() {
    let tape = Tape::<f64>::new();
    let x = tape.leaf(&[1.0, 2.0]);
    let y = tape.leaf(&[3.0]);
    let a = (x * y).sum();
    let b = (x * x).sum();
    tape.backward(a);
    assert_eq!(&*tape.grad(x), &[3.0, 3.0]);
    assert_eq!(tape.grad(y)[0], 3.0);
    tape.backward(b);
    assert_eq!(&*tape.grad(x), &[2.0, 4.0]);
    assert_eq!(tape.grad(y)[0], 0.0);
}

#[test]
fn memory_is_flat_across_iterations() {
    let n = 70_000;
    let tape = Tape::<f32>::new();
    let x = tape.leaf(&vec![0.5f32; n]).id();
    let mark = tape.mark();
    let mut reserved = Vec::new();
    for it in 0..6 {
        tape.reset_to(mark);
        tape.set_values(x, &vec![0.1 * it as f32; n]);
        let xv = tape.var(x);
        let loss = ((xv * xv + 1.0).sqrt().sin() * xv).sum() + xv.slice(0, 10).exp().sum();
        tape.backward(loss);
        assert!(tape.grad(xv)[0].is_finite());
        reserved.push(tape.reserved_bytes());
    }
    assert!(
        reserved[1..].iter().all(|&r| r == reserved[1]),
        "reserved bytes grew: {reserved:?}"
    );
}

#[test]
fn check_finite_names_the_first_op_that_produced_a_nan() {
    let tape = Tape::<f32>::new();
    tape.set_check_finite(true);
    let x = tape.leaf(&[1.0, -2.0, 3.0]);
    let y = (x * 2.0).ln().sqrt().sum();
    let _ = tape.value(y);
    let nf = tape.non_finite().expect("ln(-4) is NaN");
    assert_eq!((nf.op, nf.index, nf.in_backward), ("ln", 1, false));
    assert!(nf.to_string().contains("op `ln`"), "{nf}");
    let clean = Tape::<f32>::new();
    clean.set_check_finite(true);
    let x = clean.leaf(&[1.0, 2.0]);
    clean.backward((x * x).sum());
    assert_eq!(clean.non_finite(), None);
}

#[test]
fn gradients_are_skipped_where_nothing_needs_them() {
    let tape = Tape::<f64>::new();
    let c = tape.constant(&[1.0, 2.0]);
    let y = (c.exp() * 3.0).sum();
    assert!(!y.requires_grad());
    tape.backward(y);
    let x = tape.leaf(&[1.0]);
    let _ = (x * c).sum();
    tape.backward(y);
    assert_eq!(tape.grad(x)[0], 0.0);
}

#[test]
fn vec3_and_quaternion_helpers() {
    let tape = Tape::<f64>::new();
    let q = Quat::new(
        tape.scalar(0.5f64.sqrt()),
        tape.scalar(0.0),
        tape.scalar(0.5f64.sqrt()),
        tape.scalar(0.0),
    );
    let p = Vec3::new(tape.constant(&[1.0]), tape.constant(&[0.0]), tape.constant(&[0.0]));
    let r = q.rotate(p);
    // 90 degrees about +Y takes +X to -Z.
    let (x, y, z) = (tape.value(r.x)[0], tape.value(r.y)[0], tape.value(r.z)[0]);
    assert!(
        x.abs() < 1e-15 && y.abs() < 1e-15 && (z + 1.0).abs() < 1e-15,
        "{x} {y} {z}"
    );
    let d = Vec3::new(tape.constant(&[1.0]), tape.constant(&[-1.0]), tape.constant(&[0.0]));
    let n = Vec3::constant(&tape, [0.0, 1.0, 0.0]);
    let m = d.reflect(n);
    assert_eq!(
        [tape.value(m.x)[0], tape.value(m.y)[0], tape.value(m.z)[0]],
        [-1.0, -1.0, 0.0]
    );
    let c = Vec3::constant(&tape, [1.0, 0.0, 0.0]).cross(Vec3::constant(&tape, [0.0, 1.0, 0.0]));
    assert_eq!(
        [tape.value(c.x)[0], tape.value(c.y)[0], tape.value(c.z)[0]],
        [0.0, 0.0, 1.0]
    );

    let inputs = [
        Input::Var(vec![0.9, 0.1, -0.3, 0.2]),
        Input::Var(uniform(15, -1.0, 1.0, 4)),
    ];
    let report = gradcheck(&inputs, |_, v| {
        let q = Quat::new(v[0].slice(0, 1), v[0].slice(1, 1), v[0].slice(2, 1), v[0].slice(3, 1)).normalize();
        let p = Vec3::new(v[1].slice(0, 5), v[1].slice(5, 5), v[1].slice(10, 5));
        let r = q.rotate(p).normalize(1e-9);
        let s = r.reflect(p.normalize(1e-9)).cross(p);
        s.x + s.y * 2.0 + s.z.exp() + r.length()
    });
    assert!(report.worst_rel_error < 1e-6, "{report}");
}

#[test]
fn normalize_of_a_zero_vector_is_finite() {
    let tape = Tape::<f64>::new();
    let v = Vec3::new(tape.leaf(&[0.0]), tape.leaf(&[0.0]), tape.leaf(&[0.0]));
    let n = v.normalize(1e-6);
    let loss = n.x + n.y + n.z;
    tape.backward(loss);
    assert!(tape.value(loss)[0].is_finite() && tape.grad(v.x)[0].is_finite());
}

#[test]
fn fused_and_recomputing_backward_passes_agree() {
    // backward right after recording runs the last region forward and backward
    // in one pass; after a value() it recomputes tile values instead.
    let grads = |read_value_first: bool| {
        let tape = Tape::<f64>::new();
        let x = tape.leaf(&uniform(90_000, -2.0, 2.0, 5));
        let theta = tape.leaf(&[0.3]);
        let table = tape.leaf(&uniform(37, 0.5, 1.5, 6));
        let loss = program(&tape, x, theta, table);
        if read_value_first {
            let _ = tape.value(loss)[0];
        }
        tape.backward(loss);
        (tape.grad(x).to_vec(), tape.grad(theta)[0], tape.grad(table).to_vec())
    };
    assert!(
        grads(true) == grads(false),
        "the fused and the recomputing backward passes differ"
    );
}

#[test]
fn an_input_that_a_region_reads_but_does_not_differentiate_still_gets_the_right_gradient() {
    // Region R reads x only through a value that does not reach the loss; x's
    // gradient comes from an earlier region. Run twice so that reused buffers
    // hold stale values.
    let tape = Tape::<f64>::new();
    let x = tape.leaf(&[1.0, 2.0, 3.0]).id();
    let w = tape.leaf(&[1.0, 1.0, 1.0]).id();
    let mark = tape.mark();
    for _ in 0..2 {
        tape.reset_to(mark);
        let (x, w) = (tape.var(x), tape.var(w));
        let p = (x * x).sum();
        let q = p + 1.0;
        let unused = x * 2.0;
        let r = (w * 3.0).sum();
        let _ = unused;
        tape.backward(q + r);
        assert_eq!(&*tape.grad(x), &[2.0, 4.0, 6.0]);
        assert_eq!(&*tape.grad(w), &[3.0, 3.0, 3.0]);
    }
}
