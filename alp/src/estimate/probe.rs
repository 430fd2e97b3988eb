//! The probe as the estimate uses it: its asset, its reflectance model at
//! both precisions, its mesh's topology and what its symmetry tells.

use render::bsdf::Bsdf;
use render::mesh::EdgeAdjacency;
use render::probe::ProbeAsset;

use super::settings::SymmetrySettings;
use super::symmetry;

/// A reflectance model at both precisions the estimate works in: renders
/// in f32, outline fits in f64. Every [`Bsdf`] written generically over
/// [`autodiff::Real`] (as `render::bsdf`'s are) is one.
pub trait ProbeBsdf: Bsdf<f32> + Bsdf<f64> {}

impl<B: Bsdf<f32> + Bsdf<f64>> ProbeBsdf for B {}

/// The probe's mesh, material and topology, prepared once.
pub(in crate::estimate) struct Probe<'a> {
    pub(in crate::estimate) asset: &'a ProbeAsset,
    /// Its reflectance model: what every render of it uses.
    pub(in crate::estimate) bsdf: &'a dyn ProbeBsdf,
    pub(in crate::estimate) edges: EdgeAdjacency,
    /// Whether a turn about its axis changes its outline (`symmetry::turns_show`):
    /// each axis hypothesis is then fitted at several turns.
    pub(in crate::estimate) turns_show: bool,
    /// Whether it looks the same at every turn about its axis, where the
    /// asset tells (`symmetry::looks_alike_turned`; else its renders do).
    pub(in crate::estimate) alike_turned: Option<bool>,
    /// Whether its colours are the same all round its axis, where the asset
    /// tells (`symmetry::colours_alike_turned`): then colour cannot tell its
    /// ends apart, and the photo judges the other end.
    pub(in crate::estimate) colours_alike: Option<bool>,
}

impl<'a> Probe<'a> {
    /// `asset` (its axis along mesh +Y) of reflectance `bsdf`, prepared.
    pub(in crate::estimate) fn new(
        asset: &'a ProbeAsset,
        bsdf: &'a dyn ProbeBsdf,
        symmetry: &SymmetrySettings,
    ) -> Self {
        // The axis of revolution, found once for the three readings of it.
        let revolution = symmetry::axis_of_revolution(&asset.mesh, symmetry);
        let revolution = revolution.as_ref();
        Probe {
            asset,
            bsdf,
            edges: EdgeAdjacency::new(&asset.mesh),
            turns_show: symmetry::turns_show_about(&asset.mesh, revolution, symmetry),
            alike_turned: symmetry::alike_turned_about(asset, revolution, symmetry),
            colours_alike: symmetry::colours_alike_about(asset, revolution, symmetry),
        }
    }
}
