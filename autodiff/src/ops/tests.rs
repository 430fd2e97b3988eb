//! The elementwise ops (`map.rs`, constructors in `mod.rs`): literal forward
//! values (f32 and f64) and a central-difference gradient check in f64 away
//! from kinks. Each structural op's tests sit in its own file.

use crate::gradcheck::{Input, gradcheck, uniform};
use crate::{Real, Tape, Var};

/// Largest relative error a central-difference check accepts.
pub(super) const TOL: f64 = 1e-6;

/// Forward values of a one-input program on both float types.
fn forward_both(x: &[f64], f64_fn: impl for<'t> Fn(Var<'t, f64>) -> Var<'t, f64>) -> Vec<f64> {
    let tape = Tape::<f64>::new();
    let y = f64_fn(tape.constant(x));
    tape.value(y).to_vec()
}

fn forward_f32(x: &[f32], f: impl for<'t> Fn(Var<'t, f32>) -> Var<'t, f32>) -> Vec<f32> {
    let tape = Tape::<f32>::new();
    let y = f(tape.constant(x));
    tape.value(y).to_vec()
}

fn assert_close(got: &[f64], want: &[f64], tol: f64, what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: length");
    for (k, (g, w)) in got.iter().zip(want).enumerate() {
        let ok = (g - w).abs() <= tol * w.abs().max(1.0) || (g.is_nan() && w.is_nan()) || g == w;
        assert!(ok, "{what}[{k}]: got {g}, want {w}");
    }
}

macro_rules! unary_case {
    ($name:ident, $method:ident $(($($arg:expr),*))?, [$(($x:expr, $y:expr)),*], $lo:expr, $hi:expr) => {
        #[test]
        fn $name() {
            let xs = [$($x as f64),*];
            let ys = [$($y as f64),*];
            let got = forward_both(&xs, |v| v.$method($($(Real::c($arg)),*)?));
            assert_close(&got, &ys, 1e-12, concat!(stringify!($method), " f64"));
            let xs32: Vec<f32> = xs.iter().map(|&x| x as f32).collect();
            let got32: Vec<f64> = forward_f32(&xs32, |v| v.$method($($(Real::c($arg)),*)?)).iter().map(|&y| y as f64).collect();
            assert_close(&got32, &ys, 3e-7, concat!(stringify!($method), " f32"));
            let report = gradcheck(&[Input::Var(uniform(24, $lo, $hi, 7))], |_, x| x[0].$method($($(Real::c($arg)),*)?));
            assert!(report.worst_rel_error < TOL, "{}: {report}", stringify!($method));
        }
    };
}

use std::f64::consts::{E, FRAC_PI_2, FRAC_PI_4, PI};

unary_case!(
    sqrt_op,
    sqrt,
    [(4.0, 2.0), (2.0, std::f64::consts::SQRT_2), (0.0, 0.0)],
    0.1,
    9.0
);
unary_case!(rsqrt_op, rsqrt, [(4.0, 0.5), (0.25, 2.0)], 0.1, 9.0);
unary_case!(exp_op, exp, [(0.0, 1.0), (1.0, E), (-2.0, (-2f64).exp())], -5.0, 5.0);
unary_case!(
    ln_op,
    ln,
    [(1.0, 0.0), (E, 1.0), (0.5, -std::f64::consts::LN_2)],
    0.05,
    20.0
);
unary_case!(
    sin_op,
    sin,
    [
        (0.0, 0.0),
        (FRAC_PI_2, 1.0),
        (-FRAC_PI_4, -std::f64::consts::FRAC_1_SQRT_2)
    ],
    -9.0,
    9.0
);
unary_case!(
    cos_op,
    cos,
    [(0.0, 1.0), (PI, -1.0), (FRAC_PI_4, std::f64::consts::FRAC_1_SQRT_2)],
    -9.0,
    9.0
);
unary_case!(
    asin_op,
    asin,
    [(0.0, 0.0), (1.0, FRAC_PI_2), (-0.5, -PI / 6.0)],
    -0.95,
    0.95
);
unary_case!(
    acos_op,
    acos,
    [(1.0, 0.0), (0.0, FRAC_PI_2), (-1.0, PI), (0.5, PI / 3.0)],
    -0.95,
    0.95
);
unary_case!(abs_op, abs, [(-2.5, 2.5), (3.0, 3.0), (0.0, 0.0)], 0.1, 3.0);
unary_case!(
    sigmoid_op,
    sigmoid,
    [(0.0, 0.5), (2.0, 1.0 / (1.0 + (-2f64).exp())), (-200.0, 0.0)],
    -6.0,
    6.0
);
unary_case!(
    softplus_op,
    softplus,
    [(0.0, std::f64::consts::LN_2), (50.0, 50.0), (-30.0, (-30f64).exp())],
    -8.0,
    8.0
);
unary_case!(powf_op, powf(2.5), [(4.0, 32.0), (0.0, 0.0), (1.0, 1.0)], 0.1, 4.0);
unary_case!(
    powf_integer_negative_base,
    powf(3.0),
    [(-2.0, -8.0), (2.0, 8.0)],
    -3.0,
    3.0
);
unary_case!(
    clamp_op,
    clamp(-1.0, 2.0),
    [(-3.0, -1.0), (0.5, 0.5), (7.0, 2.0)],
    -0.9,
    1.9
);
unary_case!(huber_op, huber(1.0), [(0.5, 0.125), (-3.0, 2.5), (2.0, 1.5)], -3.0, 3.0);
unary_case!(affine_op, affine(2.0, -1.0), [(3.0, 5.0), (0.0, -1.0)], -3.0, 3.0);
unary_case!(neg_and_square, square, [(-3.0, 9.0), (0.5, 0.25)], -3.0, 3.0);

#[test]
fn powf_of_negative_base_with_fractional_exponent_is_nan() {
    let got = forward_both(&[-2.0], |v| v.powf(0.5));
    assert!(got[0].is_nan());
}

#[test]
fn floor_and_comparisons_give_values_and_no_gradient() {
    let tape = Tape::<f64>::new();
    let x = tape.leaf(&[-1.5, 0.0, 2.7, 1.0]);
    let c = tape.scalar(1.0);
    assert_eq!(&*tape.value(x.floor()), &[-2.0, 0.0, 2.0, 1.0]);
    assert_eq!(&*tape.value(x.lt(c)), &[1.0, 1.0, 0.0, 0.0]);
    assert_eq!(&*tape.value(x.le(c)), &[1.0, 1.0, 0.0, 1.0]);
    assert_eq!(&*tape.value(x.gt(c)), &[0.0, 0.0, 1.0, 0.0]);
    assert_eq!(&*tape.value(x.ge(c)), &[0.0, 0.0, 1.0, 1.0]);
    assert_eq!(&*tape.value(x.eq_mask(c)), &[0.0, 0.0, 0.0, 1.0]);
    assert!(!x.floor().requires_grad() && !x.lt(c).requires_grad());
    let y = (x.floor() * x).sum();
    tape.backward(y);
    assert_eq!(&*tape.grad(x), &[-2.0, 0.0, 2.0, 1.0]);
}

fn two_inputs() -> [Input; 2] {
    [
        Input::Var(uniform(12, 0.2, 3.0, 1)),
        Input::Var(uniform(12, -2.0, 2.0, 2)),
    ]
}

macro_rules! binary_case {
    ($name:ident, $f:ident, [$(($a:expr, $b:expr, $y:expr)),*]) => {
        #[test]
        fn $name() {
            let (a, b, y) = (vec![$($a as f64),*], vec![$($b as f64),*], vec![$($y as f64),*]);
            let tape = Tape::<f64>::new();
            let out = $f(tape.constant(&a), tape.constant(&b));
            assert_close(&tape.value(out), &y, 1e-12, stringify!($name));
            let tape = Tape::<f32>::new();
            let a32: Vec<f32> = a.iter().map(|&v| v as f32).collect();
            let b32: Vec<f32> = b.iter().map(|&v| v as f32).collect();
            let out = $f(tape.constant(&a32), tape.constant(&b32));
            let got: Vec<f64> = tape.value(out).iter().map(|&v| v as f64).collect();
            assert_close(&got, &y, 3e-7, stringify!($name));
            // Array-array, array-scalar and scalar-array (broadcast) gradients.
            let r = gradcheck(&two_inputs(), |_, x| $f(x[0], x[1]));
            assert!(r.worst_rel_error < TOL, "{}: {r}", stringify!($name));
            let r = gradcheck(&[Input::Var(uniform(9, 0.2, 3.0, 3)), Input::Var(vec![0.7])], |_, x| $f(x[0], x[1]));
            assert!(r.worst_rel_error < TOL, "{} broadcast rhs: {r}", stringify!($name));
            let r = gradcheck(&[Input::Var(vec![1.3]), Input::Var(uniform(9, -2.0, 2.0, 4))], |_, x| $f(x[0], x[1]));
            assert!(r.worst_rel_error < TOL, "{} broadcast lhs: {r}", stringify!($name));
        }
    };
}

fn add<'t, T: Real>(a: Var<'t, T>, b: Var<'t, T>) -> Var<'t, T> {
    a + b
}
fn sub<'t, T: Real>(a: Var<'t, T>, b: Var<'t, T>) -> Var<'t, T> {
    a - b
}
fn mul<'t, T: Real>(a: Var<'t, T>, b: Var<'t, T>) -> Var<'t, T> {
    a * b
}
fn div<'t, T: Real>(a: Var<'t, T>, b: Var<'t, T>) -> Var<'t, T> {
    b / (a + T::c(0.5))
}
fn pow<'t, T: Real>(a: Var<'t, T>, b: Var<'t, T>) -> Var<'t, T> {
    a.pow(b)
}
fn atan2<'t, T: Real>(a: Var<'t, T>, b: Var<'t, T>) -> Var<'t, T> {
    b.atan2(a - T::c(1.1))
}
fn min<'t, T: Real>(a: Var<'t, T>, b: Var<'t, T>) -> Var<'t, T> {
    a.min(b)
}
fn max<'t, T: Real>(a: Var<'t, T>, b: Var<'t, T>) -> Var<'t, T> {
    a.max(b)
}

binary_case!(add_op, add, [(1.0, 2.0, 3.0), (-1.5, 0.5, -1.0)]);
binary_case!(sub_op, sub, [(1.0, 2.0, -1.0), (-1.5, 0.5, -2.0)]);
binary_case!(mul_op, mul, [(3.0, 2.0, 6.0), (-1.5, 0.5, -0.75)]);
binary_case!(div_op, div, [(1.5, 6.0, 3.0), (0.0, -1.0, -2.0)]);
binary_case!(
    pow_op,
    pow,
    [(2.0, 3.0, 8.0), (4.0, 0.5, 2.0), (0.0, 2.0, 0.0), (0.0, 0.0, 1.0)]
);
binary_case!(
    atan2_op,
    atan2,
    [(2.1, 1.0, FRAC_PI_4), (0.1, 0.0, PI), (1.1, -1.0, -FRAC_PI_2)]
);
binary_case!(min_op, min, [(1.0, 2.0, 1.0), (3.0, -1.0, -1.0)]);
binary_case!(max_op, max, [(1.0, 2.0, 2.0), (3.0, -1.0, 3.0)]);

#[test]
fn min_max_split_the_gradient_on_ties_and_follow_the_winner() {
    let tape = Tape::<f64>::new();
    let a = tape.leaf(&[1.0, 2.0, 3.0]);
    let b = tape.leaf(&[1.0, 5.0, 0.0]);
    tape.backward((a.min(b) + a.max(b) * 2.0).sum());
    assert_eq!(&*tape.grad(a), &[1.5, 1.0, 2.0]);
    assert_eq!(&*tape.grad(b), &[1.5, 2.0, 1.0]);
}

#[test]
fn mul_add_and_select() {
    let tape = Tape::<f64>::new();
    let (a, b, c) = (
        tape.constant(&[2.0, -1.0]),
        tape.constant(&[3.0, 4.0]),
        tape.constant(&[1.0, 0.5]),
    );
    assert_eq!(&*tape.value(a.mul_add(b, c)), &[7.0, -3.5]);
    let mask = tape.constant(&[1.0, 0.0]);
    assert_eq!(&*tape.value(mask.select(a, b)), &[2.0, 4.0]);
    let inputs = [
        Input::Var(uniform(8, -2.0, 2.0, 5)),
        Input::Var(uniform(8, -2.0, 2.0, 6)),
        Input::Var(uniform(8, -2.0, 2.0, 8)),
    ];
    let r = gradcheck(&inputs, |_, x| x[0].mul_add(x[1], x[2]));
    assert!(r.worst_rel_error < TOL, "mul_add: {r}");
    let r = gradcheck(&inputs, |_, x| x[0].gt(x[1]).select(x[1] * x[2], x[2].exp()));
    assert!(r.worst_rel_error < TOL, "select: {r}");
}

#[test]
fn broadcast_repeats_a_scalar() {
    let tape = Tape::<f64>::new();
    assert_eq!(&*tape.value(tape.scalar(2.0).broadcast(3)), &[2.0; 3]);
    let r = gradcheck(&[Input::Var(vec![0.3])], |_, x| (x[0].broadcast(5) * x[0]).exp());
    assert!(r.worst_rel_error < TOL, "broadcast: {r}");
}

#[test]
fn stop_gradient_cuts_the_gradient() {
    let tape = Tape::<f64>::new();
    let x = tape.leaf(&[2.0]);
    tape.backward(x * x.stop_gradient());
    assert_eq!(tape.grad(x)[0], 2.0);
}

#[test]
#[should_panic(expected = "add: shape mismatch: operands have shapes [3] and [2]")]
fn shape_mismatch_names_the_op_and_both_shapes() {
    let tape = Tape::<f32>::new();
    let _ = tape.constant(&[1.0, 2.0, 3.0]) + tape.constant(&[1.0, 2.0]);
}

#[test]
fn scalars_on_the_left() {
    let tape = Tape::<f32>::new();
    let x = tape.constant(&[2.0, 4.0]);
    assert_eq!(&*tape.value(1.0 - x), &[-1.0, -3.0]);
    assert_eq!(&*tape.value(8.0 / x), &[4.0, 2.0]);
    assert_eq!(&*tape.value(3.0 * x + 1.0), &[7.0, 13.0]);
    assert_eq!(&*tape.value(-x), &[-2.0, -4.0]);
}
