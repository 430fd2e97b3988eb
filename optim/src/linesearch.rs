//! More-Thuente line search for the strong Wolfe conditions, along a projected path.
//!
//! Finds a step `a` with sufficient decrease `phi(a) <= phi(0) + c1 a phi'(0)` and
//! curvature `|phi'(a)| <= c2 |phi'(0)|`, where `phi(a) = f(P(x + a d))`.
//! The bracketing and the safeguarded cubic/quadratic steps follow
//! J. J. More and D. J. Thuente, "Line search algorithms with guaranteed sufficient
//! decrease", ACM TOMS 20(3), 1994 (MINPACK-2 `dcsrch`/`dcstep`, the search inside
//! SciPy's L-BFGS-B), with the same constants so evaluation counts compare.
//!
//! Two additions: a trial with a non-finite value or gradient is treated as an
//! infinitely high point (the bracket closes on it and the next trial bisects
//! towards the best point), and when the search stalls (bracket below `xtol`,
//! rounding errors, evaluation cap) it still returns its best point if that point
//! satisfies sufficient decrease, as L-BFGS-B does with MINPACK's warnings.

use std::fmt;

use crate::objective::all_finite;
use crate::{Bounds, Objective, OptimError};

/// Why a line search found no acceptable step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LineSearchError {
    /// The direction does not descend: `phi'(0) >= 0` or not finite.
    NotDescent,
    /// Every trial point returned a non-finite value or gradient.
    NonFinite,
    /// The bracket shrank below `xtol` (or rounding stopped progress) without a decrease.
    IntervalTooSmall,
    /// The line search's own evaluation cap was reached without a decrease.
    MaxEvals,
}

impl fmt::Display for LineSearchError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            LineSearchError::NotDescent => "direction is not a descent direction",
            LineSearchError::NonFinite => "objective was non-finite at every trial step",
            LineSearchError::IntervalTooSmall => "bracket collapsed without sufficient decrease",
            LineSearchError::MaxEvals => "evaluation cap reached without sufficient decrease",
        })
    }
}

/// Settings of the More-Thuente search; the defaults are MINPACK-2's as used by L-BFGS-B.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MoreThuente {
    /// Sufficient-decrease constant `c1` (`ftol` in MINPACK), in (0, c2).
    pub c1: f64,
    /// Curvature constant `c2` (`gtol` in MINPACK), in (c1, 1).
    pub c2: f64,
    /// Relative bracket width below which the search stops.
    pub xtol: f64,
    /// Evaluations allowed per search.
    pub max_evals: usize,
}

impl Default for MoreThuente {
    fn default() -> Self {
        MoreThuente {
            c1: 1e-3,
            c2: 0.9,
            xtol: 0.1,
            max_evals: 20,
        }
    }
}

/// Largest step tried (MINPACK's `stpmax` for an unconstrained L-BFGS-B run).
const STEP_MAX: f64 = 1e10;
/// Bisect when a bracket did not shrink to this fraction of its size two trials ago.
const SHRINK: f64 = 0.66;
/// Extrapolation range, as multiples of the last step, before a minimizer is bracketed.
const EXTRAPOLATE: (f64, f64) = (1.1, 4.0);
/// A change of the value this small, relative to it, may be rounding: a sum of
/// thousands of terms (pixels, texels) is no more exact than this.
const ROUNDING: f64 = 1e-12;

/// A point of the search: parameters, gradient and value.
#[derive(Debug, Clone)]
pub(crate) struct Point {
    pub x: Vec<f64>,
    pub grad: Vec<f64>,
    pub value: f64,
}

impl Point {
    pub fn zeros(n: usize) -> Self {
        Point {
            x: vec![0.0; n],
            grad: vec![0.0; n],
            value: 0.0,
        }
    }
}

/// The line `P(x + a d)` to search and what is known at `a = 0`.
pub(crate) struct Line<'a> {
    pub x: &'a [f64],
    pub value: f64,
    pub direction: &'a [f64],
    /// `phi'(0)`, the directional derivative along the path.
    pub slope: f64,
    /// The first trial step.
    pub first_step: f64,
}

/// Result of one search; the accepted point is left in the workspace's `best`.
pub(crate) struct Outcome {
    pub step: Result<f64, LineSearchError>,
    pub evals: usize,
    pub rejected: usize,
}

/// One end of the bracket: step, value and slope.
#[derive(Debug, Clone, Copy)]
struct End {
    step: f64,
    value: f64,
    slope: f64,
}

impl MoreThuente {
    /// Checks `0 < c1 < c2 < 1`, `xtol > 0` and at least one evaluation.
    pub(crate) fn validate(&self) -> Result<(), OptimError> {
        OptimError::check(
            self.c1 > 0.0 && self.c1 < self.c2,
            "line_search.c1",
            "must be in (0, c2)",
            self.c1,
        )?;
        OptimError::check(self.c2 < 1.0, "line_search.c2", "must be in (c1, 1)", self.c2)?;
        OptimError::check(self.xtol > 0.0, "line_search.xtol", "must be > 0", self.xtol)?;
        OptimError::check(
            self.max_evals > 0,
            "line_search.max_evals",
            "must be > 0",
            self.max_evals,
        )
    }

    /// Searches `line` from its first trial step, using at most `max_evals` evaluations.
    ///
    /// `trial` and `best` are scratch points of the problem's size; on success `best`
    /// holds the accepted point.
    pub(crate) fn search<O: Objective>(
        &self,
        objective: &mut O,
        bounds: &Bounds,
        line: &Line<'_>,
        max_evals: usize,
        trial: &mut Point,
        best: &mut Point,
    ) -> Outcome {
        let mut out = Outcome {
            step: Err(LineSearchError::NotDescent),
            evals: 0,
            rejected: 0,
        };
        let descends = line.slope < 0.0;
        if !descends {
            return out;
        }
        let max_evals = max_evals.min(self.max_evals);
        let slope_test = self.c1 * line.slope;
        let origin = End {
            step: 0.0,
            value: line.value,
            slope: line.slope,
        };
        let (mut lo, mut hi) = (origin, origin);
        let mut bracketed = false;
        // Stage 1 works on psi(a) = phi(a) - c1 a phi'(0) until a step with psi <= 0 and
        // phi' >= 0 shows that a minimizer of phi itself is bracketed.
        let mut stage1 = true;
        let mut width = STEP_MAX;
        let mut width_before = 2.0 * width;
        let mut step = line.first_step.clamp(0.0, STEP_MAX);
        let (mut step_min, mut step_max) = (0.0, step + EXTRAPOLATE.1 * step);
        let mut failure = LineSearchError::MaxEvals;

        while out.evals < max_evals {
            let value = evaluate(objective, bounds, line, step, trial);
            out.evals += 1;
            let finite = all_finite(value, &trial.grad);
            let slope = if finite {
                path_slope(bounds, line.direction, trial)
            } else {
                0.0
            };
            let decrease_test = line.value + step * slope_test;

            let curved = slope.abs() <= self.c2 * -line.slope;
            // Near a minimizer rounding hides the decrease in the value that the
            // slope still shows: there a value within rounding of phi(0) passes if
            // the slope has fallen to (1 - 2 c1) |phi'(0)| (Hager and Zhang's
            // approximate Wolfe conditions: on a quadratic, the decrease test).
            let rounding = line.value + ROUNDING * line.value.abs();
            let approximate = value <= rounding && slope <= (1.0 - 2.0 * self.c1) * -line.slope;
            if finite && curved && (value <= decrease_test || approximate) {
                std::mem::swap(trial, best);
                out.step = Ok(step);
                return out;
            }
            if !finite {
                out.rejected += 1;
                failure = LineSearchError::NonFinite;
                // An infinitely high point: close the bracket on it, bisect towards `lo`.
                hi = End {
                    step,
                    value: f64::INFINITY,
                    slope: 0.0,
                };
                bracketed = true;
                step = lo.step + 0.5 * (step - lo.step);
            } else {
                if stage1 && value <= decrease_test && slope >= 0.0 {
                    stage1 = false;
                }
                let here = End { step, value, slope };
                let shift = if stage1 && value <= lo.value && value > decrease_test {
                    slope_test
                } else {
                    0.0
                };
                let (next, moved_lo) =
                    safeguarded_step(&mut lo, &mut hi, here, shift, &mut bracketed, step_min, step_max);
                if moved_lo {
                    std::mem::swap(trial, best);
                }
                step = next;
                if bracketed {
                    if (hi.step - lo.step).abs() >= SHRINK * width_before {
                        step = lo.step + 0.5 * (hi.step - lo.step);
                    }
                    width_before = width;
                    width = (hi.step - lo.step).abs();
                }
            }
            if bracketed {
                step_min = lo.step.min(hi.step);
                step_max = lo.step.max(hi.step);
            } else {
                step_min = step + EXTRAPOLATE.0 * (step - lo.step);
                step_max = step + EXTRAPOLATE.1 * (step - lo.step);
            }
            step = step.clamp(0.0, STEP_MAX);
            if bracketed && (step <= step_min || step >= step_max || step_max - step_min <= self.xtol * step_max) {
                // MINPACK would now re-evaluate its best step and stop; `best` already holds it.
                if failure != LineSearchError::NonFinite {
                    failure = LineSearchError::IntervalTooSmall;
                }
                break;
            }
        }
        // Stalled: accept the best point if it decreased f, as L-BFGS-B accepts MINPACK's warnings.
        if lo.step > 0.0 && lo.value < line.value {
            out.step = Ok(lo.step);
        } else {
            out.step = Err(failure);
        }
        out
    }
}

/// Writes `P(x + step d)` into `trial` and evaluates it.
fn evaluate<O: Objective>(objective: &mut O, bounds: &Bounds, line: &Line<'_>, step: f64, trial: &mut Point) -> f64 {
    for (i, t) in trial.x.iter_mut().enumerate() {
        *t = (line.x[i] + step * line.direction[i]).clamp(bounds.lower()[i], bounds.upper()[i]);
    }
    trial.value = objective.eval(&trial.x, &mut trial.grad);
    trial.value
}

/// Right derivative of `phi` at the trial: coordinates pinned at a bound by the
/// projection stop moving, so they drop out of `grad . d`.
fn path_slope(bounds: &Bounds, direction: &[f64], trial: &Point) -> f64 {
    let mut slope = 0.0;
    for (i, (&d, &g)) in direction.iter().zip(&trial.grad).enumerate() {
        let x = trial.x[i];
        let pinned = (x <= bounds.lower()[i] && d < 0.0) || (x >= bounds.upper()[i] && d > 0.0);
        if !pinned {
            slope += g * d;
        }
    }
    slope
}

/// One `dcstep`: the next trial from a cubic or quadratic fit, and the updated bracket.
///
/// `lo` is the best end so far (lowest value) and `hi` the other end. In stage 1 the
/// values and slopes are those of `psi`, i.e. shifted by `shift = c1 phi'(0)` per unit
/// step. Returns the next trial and whether `here` became `lo`.
fn safeguarded_step(
    lo: &mut End,
    hi: &mut End,
    here: End,
    shift: f64,
    bracketed: &mut bool,
    step_min: f64,
    step_max: f64,
) -> (f64, bool) {
    let psi = |e: &End| End {
        step: e.step,
        value: e.value - e.step * shift,
        slope: e.slope - shift,
    };
    let (x, y, p) = (psi(lo), psi(hi), psi(&here));
    let same_sign = p.slope * x.slope.signum() >= 0.0;
    let next = if p.value > x.value {
        // Case 1: higher value; the minimizer is bracketed. Take the cubic step if it
        // is closer to the best point, else the mean of the cubic and quadratic steps.
        *bracketed = true;
        let cubic = cubic_min(x, p);
        let quadratic =
            x.step + x.slope / ((x.value - p.value) / (p.step - x.step) + x.slope) / 2.0 * (p.step - x.step);
        if (cubic - x.step).abs() < (quadratic - x.step).abs() {
            cubic
        } else {
            cubic + (quadratic - cubic) / 2.0
        }
    } else if !same_sign {
        // Case 2: slopes of opposite sign bracket a minimizer; take the step farther from `here`.
        *bracketed = true;
        let cubic = cubic_min(p, x);
        let secant = secant_step(p, x);
        if (cubic - p.step).abs() > (secant - p.step).abs() {
            cubic
        } else {
            secant
        }
    } else if p.slope.abs() < x.slope.abs() {
        // Case 3: the slope decreases in magnitude; the cubic may not have a minimizer
        // in the right direction, so fall back to the interval end.
        let cubic = cubic_min_towards(p, x, step_min, step_max);
        let secant = secant_step(p, x);
        if *bracketed {
            let pick = if (cubic - p.step).abs() < (secant - p.step).abs() {
                cubic
            } else {
                secant
            };
            let limit = p.step + SHRINK * (y.step - p.step);
            if p.step > x.step {
                pick.min(limit)
            } else {
                pick.max(limit)
            }
        } else {
            let pick = if (cubic - p.step).abs() > (secant - p.step).abs() {
                cubic
            } else {
                secant
            };
            pick.clamp(step_min, step_max)
        }
    } else if *bracketed {
        // Case 4: the slope does not decrease; minimize the cubic through `here` and `hi`
        // (bisect when `hi` is a non-finite point and has no usable value).
        if y.value.is_finite() {
            cubic_min(p, y)
        } else {
            p.step + 0.5 * (y.step - p.step)
        }
    } else if p.step > x.step {
        step_max
    } else {
        step_min
    };

    let moved_lo = p.value <= x.value;
    if moved_lo {
        if !same_sign {
            *hi = *lo;
        }
        *lo = here;
    } else {
        *hi = here;
    }
    (next, moved_lo)
}

/// Minimizer of the cubic interpolating values and slopes at `a` and `b`, measured from `a`.
fn cubic_min(a: End, b: End) -> f64 {
    let theta = 3.0 * (a.value - b.value) / (b.step - a.step) + a.slope + b.slope;
    let s = theta.abs().max(a.slope.abs()).max(b.slope.abs());
    let mut gamma = s * ((theta / s).powi(2) - (a.slope / s) * (b.slope / s)).sqrt();
    if b.step < a.step {
        gamma = -gamma;
    }
    let p = (gamma - a.slope) + theta;
    let q = ((gamma - a.slope) + gamma) + b.slope;
    a.step + p / q * (b.step - a.step)
}

/// Case 3's cubic step from `p` towards `x`, or the interval end when the cubic tends
/// to infinity in the direction of the step.
fn cubic_min_towards(p: End, x: End, step_min: f64, step_max: f64) -> f64 {
    let theta = 3.0 * (x.value - p.value) / (p.step - x.step) + x.slope + p.slope;
    let s = theta.abs().max(x.slope.abs()).max(p.slope.abs());
    let mut gamma = s * ((theta / s).powi(2) - (x.slope / s) * (p.slope / s)).max(0.0).sqrt();
    if p.step > x.step {
        gamma = -gamma;
    }
    let r = ((gamma - p.slope) + theta) / ((gamma + (x.slope - p.slope)) + gamma);
    if r < 0.0 && gamma != 0.0 {
        p.step + r * (x.step - p.step)
    } else if p.step > x.step {
        step_max
    } else {
        step_min
    }
}

/// Zero of the linear interpolation of the slopes at `p` and `x`.
fn secant_step(p: End, x: End) -> f64 {
    p.step + p.slope / (p.slope - x.slope) * (x.step - p.step)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Runs a search on a 1-D function from x = 0 along d = 1.
    fn search_1d(f: impl FnMut(&[f64], &mut [f64]) -> f64, step0: f64) -> (Outcome, Point) {
        let mut f = f;
        let mut g0 = [0.0];
        let value = f(&[0.0], &mut g0);
        let line = Line {
            x: &[0.0],
            value,
            direction: &[1.0],
            slope: g0[0],
            first_step: step0,
        };
        let (mut trial, mut best) = (Point::zeros(1), Point::zeros(1));
        let ls = MoreThuente::default();
        let out = ls.search(&mut f, &Bounds::unbounded(1), &line, 100, &mut trial, &mut best);
        (out, best)
    }

    #[test]
    fn finds_a_strong_wolfe_step_on_a_quartic() {
        // phi(a) = (a - 2)^4 / 4 - 2a: minimizer at a = 2 + 2^(1/3).
        let f = |x: &[f64], g: &mut [f64]| {
            g[0] = (x[0] - 2.0).powi(3) - 2.0;
            (x[0] - 2.0).powi(4) / 4.0 - 2.0 * x[0]
        };
        let (out, best) = search_1d(f, 1e-3);
        let step = out.step.unwrap();
        let (phi0, slope0) = (4.0, -10.0);
        assert!(best.value <= phi0 + 1e-3 * step * slope0);
        assert!(best.grad[0].abs() <= 0.9 * 10.0);
        assert_eq!(best.x[0], step);
    }

    #[test]
    fn backs_off_from_non_finite_values() {
        // f is NaN beyond a = 1; the minimizer of the finite part is at a = 0.5.
        let f = |x: &[f64], g: &mut [f64]| {
            if x[0] > 1.0 {
                g[0] = f64::NAN;
                return f64::NAN;
            }
            g[0] = 2.0 * (x[0] - 0.5);
            (x[0] - 0.5).powi(2)
        };
        let (out, best) = search_1d(f, 8.0);
        assert!(out.rejected >= 1);
        let step = out.step.unwrap();
        assert!(step <= 1.0 && best.value < 0.25, "step {step}, value {}", best.value);
    }

    #[test]
    fn takes_a_step_that_only_the_slope_shows_where_rounding_hides_the_decrease() {
        // phi(a) = 1e8 + 1e-9 (a - 1)^2 / 2 with an error in the value that grows to
        // 1e-7 at a = 1 (1e-15 of the value, as rounding might leave): the error hides
        // the decrease (5e-10), the exact slope shows it.
        let f = |x: &[f64], g: &mut [f64]| {
            g[0] = 1e-9 * (x[0] - 1.0);
            1e8 + 0.5e-9 * (x[0] - 1.0).powi(2) + 1e-7 * x[0]
        };
        let (out, best) = search_1d(f, 1.0);
        assert_eq!(out.step, Ok(1.0));
        assert_eq!(best.grad[0], 0.0);
        // A value above phi(0) by more than rounding (1e-9 of it) does not pass on its slope.
        let f = |x: &[f64], g: &mut [f64]| {
            g[0] = x[0] - 1.0;
            1.0 + 1e-9 * x[0]
        };
        let (out, _) = search_1d(f, 1.0);
        assert!(out.step.is_err(), "{:?}", out.step);
    }

    #[test]
    fn reports_a_non_descent_direction() {
        let (out, _) = search_1d(
            |x: &[f64], g: &mut [f64]| {
                g[0] = 1.0;
                x[0]
            },
            1.0,
        );
        assert_eq!(out.step, Err(LineSearchError::NotDescent));
        assert_eq!(out.evals, 0);
    }

    #[test]
    fn validates_constants() {
        let bad = MoreThuente {
            c1: 0.95,
            ..MoreThuente::default()
        };
        assert!(bad.validate().is_err());
        assert!(MoreThuente::default().validate().is_ok());
    }
}
