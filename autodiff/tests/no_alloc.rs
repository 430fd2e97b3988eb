//! Steady-state iterations allocate nothing: every buffer of the tape is
//! reused after `reset_to`. A counting global allocator counts the
//! allocations of the thread that runs the iterations (the pool's one).

use autodiff::{Tape, Vec3};

#[path = "../../tests/support/counting_alloc.rs"]
mod counting_alloc;

use counting_alloc::allocations;

#[test]
fn iterations_after_the_first_allocate_nothing() {
    // One thread: rayon's job queue is not ours to count.
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().expect("a pool");
    pool.install(|| {
        let n = 40_000;
        let tape = Tape::<f32>::new();
        let x = tape.leaf(&vec![0.25f32; n]).id();
        let table = tape.leaf(&[0.5f32; 300]).id();
        let idx: Vec<f32> = (0..n).map(|i| (i % 100) as f32).collect();
        let idx = tape.constant(&idx).id();
        let mark = tape.mark();
        let mut counts = Vec::new();
        for _ in 0..4 {
            let before = allocations();
            tape.reset_to(mark);
            let (x, table, idx) = (tape.var(x), tape.var(table), tape.var(idx));
            let v = Vec3::new(x, x.sin(), x.exp()).normalize(1e-6);
            let lit = table.gather_channel(idx, 3, 1) * v.y + v.z.slice(0, n).sqrt();
            let loss = lit.segmented_sum(idx, 100).abs().sum() + tape.concat(&[x, x]).mean();
            tape.backward(loss);
            let _ = tape.grad(table)[0] + tape.value(loss)[0];
            counts.push(allocations() - before);
        }
        assert!(
            counts[1..].iter().all(|&c| c == 0),
            "allocations per iteration: {counts:?}"
        );
    });
}
