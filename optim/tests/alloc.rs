//! Steps allocate nothing in steady state: a counting global allocator watches them.

use optim::problems::{Lighting, Rosenbrock};
use optim::schedule::Cosine;
use optim::{Adam, Bounds, GradClip, Lbfgs, ParamGroup, Plateau, Solver};

#[path = "../../tests/support/counting_alloc.rs"]
mod counting_alloc;

use counting_alloc::allocations;

/// Allocations made by `steps` calls of `step` after `warmup` calls.
fn allocations_in_steps<S: Solver, O: optim::Objective>(solver: &mut S, f: &mut O, x0: Vec<f64>) -> usize {
    let mut state = solver.init(f, x0).expect("valid settings");
    for _ in 0..5 {
        solver.step(f, &mut state);
    }
    let before = allocations();
    for _ in 0..50 {
        solver.step(f, &mut state);
        state.iter += 1;
    }
    allocations() - before
}

// One test function: each solver counted on this thread in turn.
#[test]
fn steps_allocate_nothing() {
    let mut adam = Adam::builder(100)
        .group(ParamGroup::new(0..40, 1e-3))
        .group(
            ParamGroup::new(40..100, 1e-2)
                .bounds(0.0, 2.0)
                .schedule(Cosine::new(100, 0.1).expect("valid")),
        )
        .clip(GradClip::Norm(10.0))
        .plateau(Plateau::default())
        .build()
        .expect("valid settings");
    assert_eq!(
        allocations_in_steps(&mut adam, &mut Rosenbrock, Rosenbrock::start(100)),
        0,
        "Adam"
    );

    let bounds = Bounds::uniform(32, 0.0, f64::INFINITY).expect("valid");
    let mut lbfgs = Lbfgs::builder()
        .bounds(bounds)
        .grad_tol(0.0)
        .cost_tol(0.0)
        .build()
        .expect("valid settings");
    assert_eq!(
        allocations_in_steps(&mut lbfgs, &mut Lighting::new(32, 0.05), vec![1.0; 32]),
        0,
        "L-BFGS"
    );
}
