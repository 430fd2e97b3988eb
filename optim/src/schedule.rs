//! Learning-rate schedules: a factor applied to a group's base learning rate at iteration `t`.

use std::f64::consts::PI;

use crate::OptimError;

/// A learning-rate multiplier as a function of the iteration (0-based).
///
/// Closures `Fn(usize) -> f64` are schedules, e.g. `|t| 1.0 / (1.0 + 0.01 * t as f64)`.
pub trait Schedule {
    /// The factor multiplying the base learning rate at iteration `t`.
    fn factor(&self, t: usize) -> f64;
}

impl<F: Fn(usize) -> f64> Schedule for F {
    fn factor(&self, t: usize) -> f64 {
        self(t)
    }
}

/// Factor 1 forever.
#[derive(Debug, Clone, Copy, Default)]
pub struct Constant;

impl Schedule for Constant {
    fn factor(&self, _t: usize) -> f64 {
        1.0
    }
}

/// `gamma^(t / every)`: exponential decay (`every = 1`) or step decay (`every > 1`).
#[derive(Debug, Clone, Copy)]
pub struct Decay {
    gamma: f64,
    every: usize,
}

impl Decay {
    /// Multiplies the rate by `gamma` every iteration.
    pub fn exponential(gamma: f64) -> Result<Self, OptimError> {
        Self::step(gamma, 1)
    }

    /// Multiplies the rate by `gamma` once every `every` iterations.
    pub fn step(gamma: f64, every: usize) -> Result<Self, OptimError> {
        OptimError::check(gamma > 0.0 && gamma <= 1.0, "decay.gamma", "must be in (0, 1]", gamma)?;
        OptimError::check(every > 0, "decay.every", "must be > 0", every)?;
        Ok(Decay { gamma, every })
    }
}

impl Schedule for Decay {
    fn factor(&self, t: usize) -> f64 {
        self.gamma.powf((t / self.every) as f64)
    }
}

/// Cosine annealing from 1 down to `min_factor` over `period` iterations, then flat.
#[derive(Debug, Clone, Copy)]
pub struct Cosine {
    period: usize,
    min_factor: f64,
}

impl Cosine {
    /// Anneals over `period` iterations to `min_factor` (Loshchilov & Hutter 2017, no restarts).
    pub fn new(period: usize, min_factor: f64) -> Result<Self, OptimError> {
        OptimError::check(period > 0, "cosine.period", "must be > 0", period)?;
        OptimError::check(
            (0.0..=1.0).contains(&min_factor),
            "cosine.min_factor",
            "must be in [0, 1]",
            min_factor,
        )?;
        Ok(Cosine { period, min_factor })
    }
}

impl Schedule for Cosine {
    fn factor(&self, t: usize) -> f64 {
        let progress = t.min(self.period) as f64 / self.period as f64;
        self.min_factor + (1.0 - self.min_factor) * 0.5 * (1.0 + (PI * progress).cos())
    }
}

/// Linear warm-up over `steps` iterations, then `then` (which starts counting at 0 after warm-up).
///
/// Adam's second-moment estimate is poor in the first iterations, so a ramp avoids
/// large early steps (Liu et al. 2020, "On the variance of the adaptive learning rate").
#[derive(Debug, Clone, Copy)]
pub struct Warmup<S> {
    steps: usize,
    then: S,
}

impl<S: Schedule> Warmup<S> {
    /// Ramps linearly from `1/steps` to 1 over `steps` iterations, then follows `then`.
    pub fn new(steps: usize, then: S) -> Result<Self, OptimError> {
        OptimError::check(steps > 0, "warmup.steps", "must be > 0", steps)?;
        Ok(Warmup { steps, then })
    }
}

impl<S: Schedule> Schedule for Warmup<S> {
    fn factor(&self, t: usize) -> f64 {
        if t < self.steps {
            (t + 1) as f64 / self.steps as f64
        } else {
            self.then.factor(t - self.steps)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn factors_match_their_formulas() {
        let step = Decay::step(0.5, 10).unwrap();
        assert_eq!(
            [step.factor(0), step.factor(9), step.factor(10), step.factor(25)],
            [1.0, 1.0, 0.5, 0.25]
        );
        assert_eq!(Decay::exponential(0.9).unwrap().factor(2), 0.81);
        let cos = Cosine::new(100, 0.1).unwrap();
        assert_eq!(cos.factor(0), 1.0);
        assert!((cos.factor(50) - 0.55).abs() < 1e-15);
        assert!((cos.factor(100) - 0.1).abs() < 1e-15);
        assert!((cos.factor(1000) - 0.1).abs() < 1e-15);
        let warm = Warmup::new(4, Decay::exponential(0.5).unwrap()).unwrap();
        assert_eq!(
            [warm.factor(0), warm.factor(3), warm.factor(4), warm.factor(5)],
            [0.25, 1.0, 1.0, 0.5]
        );
        let user = |t: usize| 1.0 / (1 + t) as f64;
        assert_eq!(user.factor(3), 0.25);
    }

    #[test]
    fn constructors_reject_invalid_settings() {
        assert!(Decay::exponential(1.5).is_err());
        assert!(Decay::step(0.5, 0).is_err());
        assert!(Cosine::new(0, 0.0).is_err());
        assert!(Cosine::new(10, f64::NAN).is_err());
        assert!(Warmup::new(0, Constant).is_err());
    }
}
