//! A term's weight as a function of the run's progress: the paper decays the
//! pose regularization to zero during the optimization, which keeps
//! gradients alive at the start (barycenter) and stops upside-down minima
//! (orientation) without biasing the final pose.

use std::f64::consts::PI;

use serde::Deserialize;

/// How a decaying weight falls from its initial value to zero.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DecayShape {
    /// `initial * (1 - t)`, t = progress / until.
    Linear,
    /// `initial * (1 + cos(pi t)) / 2`: flat at both ends (Loshchilov & Hutter 2017).
    Cosine,
}

/// A term's weight: constant, or decaying to zero at a given progress.
///
/// ```
/// use alp::objective::Weight;
/// let w = Weight::decay_to_zero(10.0, 0.5);
/// assert_eq!((w.at(0.0), w.at(0.25), w.at(0.5), w.at(1.0)), (10.0, 5.0, 0.0, 0.0));
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Weight {
    /// The same value for the whole run.
    Constant(f64),
    /// `initial` at progress 0, zero from progress `until` on.
    Decay {
        /// The weight at the start.
        initial: f64,
        /// The fraction of the run, in (0, 1], at which the weight reaches zero.
        until: f64,
        /// How it falls.
        shape: DecayShape,
    },
}

use crate::error::{Error, Result};

impl Weight {
    /// Linear decay from `initial` to zero at progress `until` (a fraction of the run).
    pub fn decay_to_zero(initial: f64, until: f64) -> Self {
        Weight::Decay {
            initial,
            until,
            shape: DecayShape::Linear,
        }
    }

    /// Cosine decay from `initial` to zero at progress `until`.
    pub fn cosine_to_zero(initial: f64, until: f64) -> Self {
        Weight::Decay {
            initial,
            until,
            shape: DecayShape::Cosine,
        }
    }

    /// The weight at `progress` in [0, 1] (the fraction of the run done).
    pub fn at(&self, progress: f64) -> f64 {
        match *self {
            Weight::Constant(w) => w,
            Weight::Decay { initial, until, shape } => {
                let t = (progress / until).clamp(0.0, 1.0);
                match shape {
                    DecayShape::Linear => initial * (1.0 - t),
                    DecayShape::Cosine => initial * 0.5 * (1.0 + (PI * t).cos()),
                }
            }
        }
    }

    /// Fails unless the weight is finite and non-negative (a negative weight
    /// would reward the error it measures) and `until` is in (0, 1].
    pub fn validate(&self) -> Result<()> {
        let (value, until) = match *self {
            Weight::Constant(w) => (w, 1.0),
            Weight::Decay { initial, until, .. } => (initial, until),
        };
        if !(value.is_finite() && value >= 0.0) {
            return Err(Error::invalid("weight", format!("{value} must be finite and >= 0")));
        }
        if !(until > 0.0 && until <= 1.0) {
            return Err(Error::invalid(
                "until",
                format!("{until} must be in (0, 1]: the fraction of the run at which the weight reaches zero"),
            ));
        }
        Ok(())
    }
}

impl From<f64> for Weight {
    fn from(w: f64) -> Self {
        Weight::Constant(w)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_follow_their_schedules() {
        assert_eq!(Weight::from(0.5).at(0.7), 0.5);
        let linear = Weight::decay_to_zero(10.0, 0.5);
        assert_eq!(
            [
                linear.at(0.0),
                linear.at(0.1),
                linear.at(0.25),
                linear.at(0.5),
                linear.at(0.9)
            ],
            [10.0, 8.0, 5.0, 0.0, 0.0]
        );
        let cosine = Weight::cosine_to_zero(2.0, 1.0);
        assert_eq!(cosine.at(0.0), 2.0);
        assert!((cosine.at(0.5) - 1.0).abs() < 1e-15);
        assert!(cosine.at(1.0).abs() < 1e-15);
        // Flat at the start, unlike the linear decay.
        assert!(2.0 - cosine.at(0.01) < 1e-3);
    }

    #[test]
    fn bad_weights_are_errors_naming_the_rule() {
        for (w, field) in [
            (Weight::from(-1.0), "weight"),
            (Weight::from(f64::NAN), "weight"),
            (Weight::from(f64::INFINITY), "weight"),
            (Weight::decay_to_zero(-2.0, 0.5), "weight"),
            (Weight::decay_to_zero(1.0, 0.0), "until"),
            (Weight::decay_to_zero(1.0, 1.5), "until"),
            (Weight::cosine_to_zero(1.0, f64::NAN), "until"),
        ] {
            let e = w.validate().expect_err("invalid");
            assert_eq!(e.field_name(), Some(field), "{e}");
        }
        assert!(Weight::decay_to_zero(0.0, 1.0).validate().is_ok());
    }
}
