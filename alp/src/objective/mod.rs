//! The declarative objective of the single-image estimation (PAPER.md,
//! "Single-image estimation"):
//!
//! ```text
//! Loss = L_rgb + L_mask + lambda1 L_pose_reg + lambda2 L_light_reg
//! ```
//!
//! as a list of weighted [`Term`]s, each recorded on the tape from what the
//! phase has, each reporting its own value and gradient norm. Every term
//! belongs to one or both [`Phase`]s: the pose phases (the pose optimised,
//! the map held; the soft mask and the rendered image recorded) and the
//! lighting phase (the map optimised at the found pose; its pixels by the
//! light transport, [`render::transport::TransportOp`]). A term declared
//! for a phase that does not record what it reads is an error, never
//! silence.
//!
//! ```
//! use alp::objective::{Barycenter, Chamfer, LeastSquaresData, LightSmoothness, MaskL1, NeighbourSmoothness, Objective, OrientationPrior, Phase, Phases, RgbL1, Weight, Weighting};
//! let objective = Objective::new()
//!     .term(RgbL1::log())
//!     .term(MaskL1)
//!     .term(Chamfer.weight(0.5))
//!     .term(Barycenter.weight(Weight::decay_to_zero(10.0, 1.0)))
//!     .term(OrientationPrior::front_facing().weight(Weight::decay_to_zero(0.1, 1.0)))
//!     .term(LeastSquaresData)
//!     .term(NeighbourSmoothness::charbonnier(0.05).weight(1e-2))
//!     .term(LightSmoothness::new(2.0).weight(1e-3));
//! assert!(objective.validate().is_ok());
//! assert_eq!(objective.names_in(Phase::Lighting), ["data_least_squares", "neighbour_smoothness", "light_smoothness"]);
//! // The mask terms read the soft mask, which the lighting phase does not record.
//! let wrong = Objective::new().term(MaskL1.weight(1.0).in_phases(Phases::LIGHTING));
//! assert!(wrong.validate().unwrap_err().to_string().contains("soft mask"));
//! ```
//!
//! The same objective as a JSON file: see [`Objective::from_json_str`]. A
//! new term implements [`Term`] over tape ops and checks its gradient with
//! [`testing::check_term`] (`examples/custom_loss.rs`).

mod data_least_squares;
mod file;
mod latitude_prior;
mod light_smoothness;
mod map_prior;
mod mask;
mod neighbour_smoothness;
mod pose_prior;
mod rgb;
pub mod testing;
mod weight;

use autodiff::{Tape, Var};
use glam::Quat;
use render::camera::Camera;
use render::lookup::ImageVars;
use render::posed::PoseVars;
use render::silhouette::{ReferenceMask, SoftMask};
use serde::Serialize;

use crate::error::{Error, Result};

pub use data_least_squares::{DataTerm, LeastSquaresData};
pub use latitude_prior::{Bands, LatitudePrior};
pub use light_smoothness::LightSmoothness;
pub use map_prior::{MapPrior, MapPriorOp, summed_curvature};
pub use mask::{Chamfer, MaskL1};
pub use neighbour_smoothness::{
    DARK_LEVEL, LightingInputs, NeighbourSmoothness, Pair, Prior, PriorBasis, Smoothness, clipped_lights,
};
pub use pose_prior::{Barycenter, OrientationPrior};
pub use rgb::{DARK_FRACTION, RgbL1, RgbVariant, mask_mean_luminance};
pub use weight::{DecayShape, Weight};

/// The estimate's phases, in which the objective's terms are evaluated.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Phase {
    /// The pose optimised, the map held: the outline fits (soft mask) and
    /// the joint rounds (soft mask and rendered image).
    Pose,
    /// The output map optimised at the found pose: the rendered pixels are
    /// the light transport applied to the map on the tape.
    Lighting,
}

impl Phase {
    /// Both phases, in order.
    pub const ALL: [Phase; 2] = [Phase::Pose, Phase::Lighting];

    /// The name objective files and reports use.
    pub fn name(self) -> &'static str {
        match self {
            Phase::Pose => "pose",
            Phase::Lighting => "lighting",
        }
    }

    /// What the phase records for its terms (the pose, the camera and the
    /// photo's mask always: constants in the lighting phase).
    pub fn records(self) -> &'static [Input] {
        match self {
            Phase::Pose => &[Input::SoftMask, Input::Image],
            Phase::Lighting => &[Input::Image, Input::Env, Input::LightingData],
        }
    }
}

/// A set of phases: where a term is evaluated.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Phases {
    pose: bool,
    lighting: bool,
}

impl Phases {
    /// No phase (an error in an objective).
    pub const NONE: Phases = Phases {
        pose: false,
        lighting: false,
    };
    /// The pose phases.
    pub const POSE: Phases = Phases {
        pose: true,
        lighting: false,
    };
    /// The lighting phase.
    pub const LIGHTING: Phases = Phases {
        pose: false,
        lighting: true,
    };
    /// Both.
    pub const BOTH: Phases = Phases {
        pose: true,
        lighting: true,
    };

    /// Whether `phase` is in the set.
    pub fn contains(self, phase: Phase) -> bool {
        match phase {
            Phase::Pose => self.pose,
            Phase::Lighting => self.lighting,
        }
    }

    /// The set with `phase` added.
    pub fn with(self, phase: Phase) -> Phases {
        match phase {
            Phase::Pose => Phases { pose: true, ..self },
            Phase::Lighting => Phases { lighting: true, ..self },
        }
    }

    /// The phases in the set, in order.
    pub fn iter(self) -> impl Iterator<Item = Phase> {
        Phase::ALL.into_iter().filter(move |&p| self.contains(p))
    }
}

/// What a term may read beyond the pose, camera and photo's mask, which
/// every phase records.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Input {
    /// The rendered soft mask ([`TermContext::soft_mask`]).
    SoftMask,
    /// The rendered image and the photo at its pixels ([`TermContext::image`]).
    Image,
    /// The env map on the tape ([`TermContext::env`]).
    Env,
    /// The lighting solve's data term and prior basis ([`TermContext::lighting`]).
    LightingData,
}

impl Input {
    fn describe(self) -> &'static str {
        match self {
            Input::SoftMask => "the soft mask",
            Input::Image => "the rendered image",
            Input::Env => "the env map as a variable",
            Input::LightingData => "the lighting solve's data",
        }
    }
}

/// A form the exact least-squares lighting solve covers: a term that says
/// it has one is compiled into that solve when every lighting term has one.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LeastSquaresForm {
    /// The weighted squared error of the pixels ([`LeastSquaresData`]).
    Data,
    /// The neighbour smoothness ([`NeighbourSmoothness`]).
    Smoothness(NeighbourSmoothness),
    /// The latitude prior ([`LatitudePrior`]).
    Latitude(LatitudePrior),
}

impl LeastSquaresForm {
    /// The prior over the map that the form is at `weight` (relative to the
    /// data term's) on `basis`; `None` for the data term.
    pub fn prior(&self, basis: &PriorBasis, weight: f64) -> Option<Box<dyn MapPrior>> {
        match self {
            LeastSquaresForm::Data => None,
            LeastSquaresForm::Smoothness(shape) => Some(Box::new(basis.prior(&shape.at_weight(weight)))),
            LeastSquaresForm::Latitude(latitude) => Some(Box::new(latitude.bands(basis, weight))),
        }
    }
}

/// One term of the loss: a scalar recorded on the tape from the context.
///
/// Implement it over tape ops (their gradients come from the ops' own
/// vector-Jacobian products) and check it with [`testing::check_term`].
pub trait Term: Send + Sync {
    /// The name reports and objective files use (`snake_case`).
    fn name(&self) -> &str;

    /// The term's value (a length-1 array) on `ctx.tape`, or `None` when an
    /// input it needs is absent in this stage of its phase (the RGB term
    /// while only the silhouette is fitted).
    fn evaluate<'t>(&self, ctx: &TermContext<'_, 't>) -> Result<Option<Var<'t, f64>>>;

    /// What the term reads beyond what every phase records: a phase that
    /// does not record it cannot evaluate the term.
    fn reads(&self) -> &'static [Input] {
        &[]
    }

    /// The phases that evaluate the term unless the objective says
    /// otherwise ([`WeightedTerm::in_phases`]): the pose phases.
    fn phases(&self) -> Phases {
        Phases::POSE
    }

    /// The term's form in the exact lighting solve, if it has one.
    fn least_squares_form(&self) -> Option<LeastSquaresForm> {
        None
    }
}

/// What the terms may read: the phase's recorded quantities and the photo's.
pub struct TermContext<'a, 't> {
    /// The phase evaluating the terms.
    pub phase: Phase,
    /// The tape everything is recorded on.
    pub tape: &'t Tape<f64>,
    /// The probe's pose (the optimised parameters; constants in the
    /// lighting phase).
    pub pose: &'a PoseVars<'t, f64>,
    /// The photo's camera.
    pub camera: &'a Camera,
    /// The photo's mask, prepared for the mask losses.
    pub reference: &'a ReferenceMask,
    /// The rendered soft mask, when the phase records it.
    pub soft_mask: Option<&'a SoftMask<'a, 't, f64>>,
    /// The rendered image and the photo at the probe's pixels, when the phase renders.
    pub image: Option<ImageTerms<'a, 't>>,
    /// The env map on the tape, when the phase optimises it.
    pub env: Option<&'a ImageVars<'t, f64>>,
    /// The lighting solve's data term and prior basis (the lighting phase).
    pub lighting: Option<&'a LightingInputs>,
    /// The canonical front-facing orientation (`estimate::pose::hypotheses::front_facing`).
    pub front_facing: Quat,
    /// The fraction of the run done, in [0, 1]: what weight schedules follow.
    pub progress: f64,
    /// Seed of the terms' random choices (vary it per iteration).
    pub seed: u64,
}

impl TermContext<'_, '_> {
    /// The image diagonal in pixels: the scale that makes pixel distances
    /// comparable across resolutions.
    pub fn diagonal_px(&self) -> f64 {
        (self.camera.width as f64).hypot(self.camera.height as f64)
    }
}

/// The rendered image and the photo at the pixels the probe covers.
#[derive(Clone, Copy, Debug)]
pub struct ImageTerms<'a, 't> {
    pixels: &'a [u32],
    rendered: [Var<'t, f64>; 3],
    target: &'a [[f64; 3]],
    weight: &'a [f64],
    level: f64,
}

impl<'a, 't> ImageTerms<'a, 't> {
    /// The rendered RGB (one array per channel) at row-major `pixels`, the
    /// photo's RGB there (`target`), each pixel's data `weight` (1 for a
    /// usable pixel, 0 for one outside the photo's mask, partly covered or
    /// clipped) and the photo's `level`, its mean luminance inside the mask
    /// ([`mask_mean_luminance`]), which sets the scale of the relative, log
    /// and tone-mapped L1: fixed for the run, so that the loss does not move
    /// with the pixels the pose happens to cover.
    ///
    /// Panics when the arrays' lengths differ (a programming error); fails
    /// on a negative or non-finite weight or target, or a level that is not
    /// finite and positive.
    pub fn new(
        pixels: &'a [u32],
        rendered: [Var<'t, f64>; 3],
        target: &'a [[f64; 3]],
        weight: &'a [f64],
        level: f64,
    ) -> Result<Self> {
        let lens = [
            rendered[0].len(),
            rendered[1].len(),
            rendered[2].len(),
            target.len(),
            weight.len(),
        ];
        assert!(
            lens.iter().all(|&l| l == pixels.len()),
            "ImageTerms::new: {} pixels, but rendered channels [{}, {}, {}], target [{}], weight [{}]",
            pixels.len(),
            lens[0],
            lens[1],
            lens[2],
            lens[3],
            lens[4]
        );
        if let Some(w) = weight.iter().find(|w| !(w.is_finite() && **w >= 0.0)) {
            return Err(Error::invalid(
                "weight",
                format!("data weight {w} must be finite and >= 0"),
            ));
        }
        if target.iter().flatten().any(|t| !(t.is_finite() && *t >= 0.0)) {
            return Err(Error::invalid("target", "holds NaN, infinite or negative radiance"));
        }
        if !(level.is_finite() && level > 0.0) {
            return Err(Error::invalid(
                "level",
                format!("the photo's mean luminance {level} must be finite and > 0"),
            ));
        }
        Ok(ImageTerms {
            pixels,
            rendered,
            target,
            weight,
            level,
        })
    }

    /// Row-major indices of the probe's pixels.
    pub fn pixels(&self) -> &'a [u32] {
        self.pixels
    }

    /// The rendered radiance, one array per channel aligned with [`pixels`](Self::pixels).
    pub fn rendered(&self) -> [Var<'t, f64>; 3] {
        self.rendered
    }

    /// The photo's radiance at the pixels.
    pub fn target(&self) -> &'a [[f64; 3]] {
        self.target
    }

    /// Each pixel's data weight (0: excluded).
    pub fn weight(&self) -> &'a [f64] {
        self.weight
    }

    /// The photo's mean luminance inside its mask.
    pub fn level(&self) -> f64 {
        self.level
    }
}

/// A term, its weight and its phases, as the objective holds it.
pub struct WeightedTerm {
    term: Box<dyn Term>,
    weight: Weight,
    phases: Option<Phases>,
}

impl WeightedTerm {
    /// The term.
    pub fn term(&self) -> &dyn Term {
        self.term.as_ref()
    }

    /// Its weight.
    pub fn weight(&self) -> Weight {
        self.weight
    }

    /// The same term evaluated in `phases` instead of its own
    /// ([`Term::phases`]): an RGB L1 minimised by the lighting phase too.
    pub fn in_phases(self, phases: Phases) -> Self {
        WeightedTerm {
            phases: Some(phases),
            ..self
        }
    }

    /// The phases that evaluate it.
    pub fn phases(&self) -> Phases {
        self.phases.unwrap_or_else(|| self.term.phases())
    }
}

impl<T: Term + 'static> From<T> for WeightedTerm {
    /// The term at weight 1.
    fn from(term: T) -> Self {
        term.weight(1.0)
    }
}

/// `.weight(w)` on every term: `Chamfer.weight(0.5)`.
pub trait Weighting: Term + Sized + 'static {
    /// The term with weight `weight` (a number or a [`Weight`] schedule).
    fn weight(self, weight: impl Into<Weight>) -> WeightedTerm {
        WeightedTerm {
            term: Box::new(self),
            weight: weight.into(),
            phases: None,
        }
    }
}

impl<T: Term + 'static> Weighting for T {}

/// A weighted sum of terms.
#[derive(Default)]
pub struct Objective {
    terms: Vec<WeightedTerm>,
}

impl std::fmt::Debug for Objective {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_map()
            .entries(self.terms.iter().map(|t| (t.term.name(), t.weight)))
            .finish()
    }
}

/// A term's value in one evaluation.
#[derive(Clone, Debug)]
pub struct TermValue<'t> {
    /// The term's name.
    pub name: String,
    /// Its weight at the evaluation's progress.
    pub weight: f64,
    /// Its (unweighted) value.
    pub value: Var<'t, f64>,
}

/// The objective recorded on a tape: the total and each term that applied.
#[derive(Clone, Debug)]
pub struct Evaluation<'t> {
    /// The weighted sum of the terms: what the optimiser minimises.
    pub total: Var<'t, f64>,
    /// Each term that applied in this phase, in the objective's order.
    pub terms: Vec<TermValue<'t>>,
}

/// One term's account of an iteration.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TermReport {
    /// The term's name.
    pub name: String,
    /// Its weight at this progress.
    pub weight: f64,
    /// Its unweighted value.
    pub value: f64,
    /// The norm of its weighted gradient, `weight * |d term / d x|`: what it
    /// contributes to the step (None where not measured: each norm costs a
    /// backward pass).
    pub gradient_norm: Option<f64>,
}

impl Objective {
    /// No terms.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds a term (at weight 1 unless given with `.weight(w)`).
    pub fn term(mut self, term: impl Into<WeightedTerm>) -> Self {
        self.terms.push(term.into());
        self
    }

    /// The terms and weights of the estimate. The pose phases: relative L1
    /// on RGB (weight 1), mask L1 (1) and Chamfer (1, in image diagonals),
    /// the barycenter (10) and front-facing orientation (0.1) priors
    /// decaying linearly to zero by progress 0.5 (the end of the estimate's
    /// silhouette phase: they guide the silhouette fit from a rough start
    /// and must not bias the final pose). The lighting phase: the weighted
    /// least-squares data term (1) and the neighbour smoothness, linear
    /// past an edge of 0.05 of the local level (1e-2): sharp where the data
    /// show an edge, strong elsewhere.
    pub fn paper_default() -> Self {
        Objective::new()
            .term(RgbL1::relative())
            .term(MaskL1)
            .term(Chamfer)
            .term(Barycenter.weight(Weight::decay_to_zero(10.0, 0.5)))
            .term(OrientationPrior::front_facing().weight(Weight::decay_to_zero(0.1, 0.5)))
            .term(LeastSquaresData)
            .term(NeighbourSmoothness::charbonnier(0.05).weight(1e-2))
    }

    /// The objective less the terms named `names` (an ablation).
    pub fn without(mut self, names: &[&str]) -> Self {
        self.terms.retain(|t| !names.contains(&t.term.name()));
        self
    }

    /// The terms in order.
    pub fn terms(&self) -> &[WeightedTerm] {
        &self.terms
    }

    /// The terms `phase` evaluates, in order.
    pub fn terms_in(&self, phase: Phase) -> impl Iterator<Item = &WeightedTerm> {
        self.terms.iter().filter(move |t| t.phases().contains(phase))
    }

    /// The names of the terms `phase` evaluates, in order.
    pub fn names_in(&self, phase: Phase) -> Vec<&str> {
        self.terms_in(phase).map(|t| t.term.name()).collect()
    }

    /// Fails on an objective without terms or with an invalid weight, on a
    /// term that no phase evaluates, and on one declared for a phase that
    /// does not record what it reads.
    pub fn validate(&self) -> Result<()> {
        if self.terms.is_empty() {
            return Err(Error::invalid("objective", "has no terms"));
        }
        for t in &self.terms {
            let name = t.term.name();
            t.weight
                .validate()
                .map_err(|e| Error::invalid(format!("{name} {}", e.field_name().unwrap_or("weight")), e.rule()))?;
            let phases = t.phases();
            if phases == Phases::NONE {
                return Err(Error::invalid(
                    format!("term `{name}`"),
                    "is evaluated by no phase: declare it for the pose or the lighting phase",
                ));
            }
            for phase in phases.iter() {
                if let Some(input) = t.term.reads().iter().find(|i| !phase.records().contains(i)) {
                    let recorded = Phase::ALL
                        .iter()
                        .filter(|p| p.records().contains(input))
                        .map(|p| p.name())
                        .collect::<Vec<_>>();
                    return Err(Error::invalid(
                        format!("term `{name}`"),
                        format!(
                            "is declared for the {} phase, which cannot evaluate it: it reads {}, which only the {} phase records",
                            phase.name(),
                            input.describe(),
                            recorded.join(" and ")
                        ),
                    ));
                }
            }
        }
        Ok(())
    }

    /// Records every term of `ctx.phase` that applies in `ctx` and their
    /// weighted sum.
    ///
    /// Terms at weight 0 are reported but left out of the total (a NaN in
    /// an unused term cannot poison it). Fails when `ctx.progress` is
    /// outside [0, 1], the objective is invalid, a term fails or returns
    /// more than one value, or no term applies.
    pub fn evaluate<'t>(&self, ctx: &TermContext<'_, 't>) -> Result<Evaluation<'t>> {
        self.validate()?;
        if !(0.0..=1.0).contains(&ctx.progress) {
            return Err(Error::invalid(
                "progress",
                format!("{} must be in [0, 1] (the fraction of the run done)", ctx.progress),
            ));
        }
        let mut terms = Vec::with_capacity(self.terms.len());
        let mut total: Option<Var<'t, f64>> = None;
        for t in self.terms_in(ctx.phase) {
            let Some(value) = t.term.evaluate(ctx)? else { continue };
            let name = t.term.name();
            if value.len() != 1 {
                return Err(Error::invalid(
                    format!("term `{name}`"),
                    format!("returned {} values; a term is a scalar", value.len()),
                ));
            }
            let weight = t.weight.at(ctx.progress);
            if weight != 0.0 {
                let weighted = value * weight;
                total = Some(total.map_or(weighted, |acc| acc + weighted));
            }
            terms.push(TermValue {
                name: name.to_string(),
                weight,
                value,
            });
        }
        if terms.is_empty() {
            let names = self.names_in(ctx.phase);
            return Err(Error::invalid(
                "objective",
                format!(
                    "none of its {} phase's terms ({}) applies: the phase records none of their inputs",
                    ctx.phase.name(),
                    names.join(", ")
                ),
            ));
        }
        Ok(Evaluation {
            total: total.unwrap_or_else(|| ctx.tape.scalar(0.0)),
            terms,
        })
    }
}

impl<'t> Evaluation<'t> {
    /// Each term's unweighted value, by name.
    pub fn values(&self) -> std::collections::BTreeMap<String, f64> {
        self.terms
            .iter()
            .map(|t| (t.name.clone(), t.value.tape().item(t.value)))
            .collect()
    }

    /// Each term's weighted gradient norm `weight * |d term / d wrt|` over
    /// the leaves `wrt` (e.g. the pose parameters), one backward pass per
    /// term with a non-zero weight. Afterwards the tape holds the gradient
    /// of the total, as after `tape.backward(total)`.
    ///
    /// Fails when one of `wrt` is not differentiated (a constant).
    pub fn gradient_norms(&self, wrt: &[Var<'t, f64>]) -> Result<Vec<f64>> {
        if let Some(k) = wrt.iter().position(|v| !v.requires_grad()) {
            return Err(Error::invalid(
                "gradient norms",
                format!("variable {k} is a constant: gradients are taken with respect to leaves"),
            ));
        }
        let tape = self.total.tape();
        let norm = |of: Var<'t, f64>| {
            tape.backward(of);
            wrt.iter()
                .map(|&v| tape.grad(v).iter().map(|g| g * g).sum::<f64>())
                .sum::<f64>()
                .sqrt()
        };
        let norms = self
            .terms
            .iter()
            .map(|t| if t.weight == 0.0 { 0.0 } else { t.weight * norm(t.value) })
            .collect();
        tape.backward(self.total);
        Ok(norms)
    }

    /// Each term's name, weight, value and weighted gradient norm over
    /// `wrt` (see [`gradient_norms`](Self::gradient_norms), whose backward
    /// passes it runs).
    pub fn report(&self, wrt: &[Var<'t, f64>]) -> Result<Vec<TermReport>> {
        let norms = self.gradient_norms(wrt)?;
        Ok(self
            .value_report()
            .into_iter()
            .zip(norms)
            .map(|(t, norm)| TermReport {
                gradient_norm: Some(norm),
                ..t
            })
            .collect())
    }

    /// Each term's name, weight and value, without the gradient norms (no
    /// backward pass).
    pub fn value_report(&self) -> Vec<TermReport> {
        self.terms
            .iter()
            .map(|t| TermReport {
                name: t.name.clone(),
                weight: t.weight,
                value: t.value.tape().item(t.value),
                gradient_norm: None,
            })
            .collect()
    }
}
