//! `L_light_reg = |L_i(w) - L_i(w + dw)|_1`, w uniform over the sphere, dw
//! a small normal perturbation: smoothness that fills directions the probe
//! sees poorly from confident neighbours, and keeps pose errors from being
//! "fixed" by high-frequency light.

use std::f32::consts::PI;

use autodiff::{Var, Vec3 as Vec3Var};
use glam::Vec3;
use render::sampling::{Frame, Rng, sample_uniform_sphere};

use super::{Input, Phases, Term, TermContext};
use crate::error::{Error, Result};

/// The random stream of the directions (any fixed number: other samplers
/// seeded alike draw other numbers).
const DIRECTION_STREAM: u64 = 0x5100_7e55;

/// Mean `|L(w) - L(w')|` over `directions` random pairs, divided by the
/// mean `L(w)`: scale-free, like the linear lighting solve's smoothness,
/// so one weight suits any exposure. `w` is uniform on the sphere and `w'`
/// is `w` moved along a great circle by an angle whose tangent-plane
/// components are normal with standard deviation `sigma_deg`. The pairs are
/// drawn from the context's seed: vary it per iteration, as the paper does.
///
/// Applies when the env map is on the tape ([`TermContext::env`]): in the
/// lighting phase. Its pairs are drawn from the context's seed, which the
/// lighting phase holds fixed over its solve.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightSmoothness {
    sigma_deg: f64,
    directions: usize,
}

impl LightSmoothness {
    /// 1024 pairs at perturbation `sigma_deg` (degrees, in (0, 90]).
    pub fn new(sigma_deg: f64) -> Self {
        LightSmoothness {
            sigma_deg,
            directions: 1024,
        }
    }

    /// The same with `directions` pairs (at least 1).
    pub fn directions(self, directions: usize) -> Self {
        LightSmoothness { directions, ..self }
    }

    /// The perturbation's standard deviation, degrees.
    pub fn sigma_deg(&self) -> f64 {
        self.sigma_deg
    }

    /// Number of direction pairs per evaluation.
    pub fn direction_count(&self) -> usize {
        self.directions
    }

    /// Fails unless sigma is in (0, 90] degrees and there is a direction.
    pub fn validate(&self) -> Result<()> {
        if !(self.sigma_deg > 0.0 && self.sigma_deg <= 90.0) {
            return Err(Error::invalid(
                "sigma_deg",
                format!("{} must be in (0, 90] degrees", self.sigma_deg),
            ));
        }
        if self.directions == 0 {
            return Err(Error::invalid("directions", "must be at least 1"));
        }
        Ok(())
    }

    /// The direction pairs (w, w') for `seed`.
    fn pairs(&self, seed: u64) -> (Vec<Vec3>, Vec<Vec3>) {
        let sigma = (self.sigma_deg as f32).to_radians();
        let mut rng = Rng::new(seed, DIRECTION_STREAM);
        (0..self.directions)
            .map(|_| {
                let w = sample_uniform_sphere(rng.next_2d());
                let frame = Frame::from_normal(w);
                // A 2D isotropic normal offset in polar form (Box-Muller):
                // Rayleigh-distributed angle, uniform heading; `1 - u` keeps
                // the logarithm finite.
                let (u1, u2) = (rng.next_f32(), rng.next_f32());
                let angle = sigma * (-2.0 * (1.0 - u1).ln()).sqrt();
                let heading = frame.s * (2.0 * PI * u2).cos() + frame.t * (2.0 * PI * u2).sin();
                (w, w * angle.cos() + heading * angle.sin())
            })
            .unzip()
    }
}

/// Unit directions as constant arrays on the tape.
fn direction_vars<'t>(tape: &'t autodiff::Tape<f64>, d: &[Vec3]) -> Vec3Var<'t, f64> {
    let column = |f: fn(&Vec3) -> f32| tape.constant(&d.iter().map(|v| f(v) as f64).collect::<Vec<_>>());
    Vec3Var::new(column(|v| v.x), column(|v| v.y), column(|v| v.z))
}

impl Term for LightSmoothness {
    fn name(&self) -> &str {
        "light_smoothness"
    }

    fn reads(&self) -> &'static [Input] {
        &[Input::Env]
    }

    fn phases(&self) -> Phases {
        Phases::LIGHTING
    }

    fn evaluate<'t>(&self, ctx: &TermContext<'_, 't>) -> Result<Option<Var<'t, f64>>> {
        let Some(env) = ctx.env else { return Ok(None) };
        self.validate()?;
        let (w, moved) = self.pairs(ctx.seed);
        let at_w = env.env_radiance(direction_vars(ctx.tape, &w));
        let at_moved = env.env_radiance(direction_vars(ctx.tape, &moved));
        let difference = (0..3)
            .map(|c| (at_w[c] - at_moved[c]).abs().sum())
            .reduce(|a, b| a + b)
            .expect("three channels");
        let level = at_w
            .into_iter()
            .map(|l| l.sum())
            .reduce(|a, b| a + b)
            .expect("three channels");
        // The ratio of sums is the ratio of means (both over 3 N values).
        Ok(Some(difference / level.max_scalar(1e-30)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pairs_are_deterministic_unit_and_sigma_apart() {
        let term = LightSmoothness::new(3.0).directions(4000);
        let (w, moved) = term.pairs(7);
        assert_eq!(term.pairs(7), (w.clone(), moved.clone()));
        assert_ne!(term.pairs(8).0, w);
        let mut mean_square = 0.0;
        for (a, b) in w.iter().zip(&moved) {
            assert!((a.length() - 1.0).abs() < 1e-5 && (b.length() - 1.0).abs() < 1e-5);
            mean_square += (a.dot(*b).clamp(-1.0, 1.0).acos().to_degrees() as f64).powi(2) / 4000.0;
        }
        // Two normal components of 3 degrees each: E[angle^2] = 2 sigma^2.
        assert!((mean_square / 18.0 - 1.0).abs() < 0.1, "E[angle^2] = {mean_square}");
        // Uniform on the sphere: the mean direction is near the centre.
        let mean = w.iter().copied().sum::<Vec3>() / 4000.0;
        assert!(mean.length() < 0.05, "{mean}");
    }

    #[test]
    fn bad_settings_are_errors() {
        for (term, field) in [
            (LightSmoothness::new(0.0), "sigma_deg"),
            (LightSmoothness::new(f64::NAN), "sigma_deg"),
            (LightSmoothness::new(120.0), "sigma_deg"),
            (LightSmoothness::new(2.0).directions(0), "directions"),
        ] {
            assert_eq!(term.validate().unwrap_err().field_name(), Some(field));
        }
    }
}
