//! `L_pose_reg = |B(M_render) - B(M_ref)|^2 + |q - q_ref|^2`: the pose
//! regularization, which the paper decays to zero during the run (give
//! these terms a [`Weight::decay_to_zero`](super::Weight::decay_to_zero)).

use autodiff::Var;

use super::{Term, TermContext};
use crate::error::Result;

/// Squared distance between the barycenters of the rendered soft mask and
/// of the photo's mask, in image diagonals: its gradient pulls the probe
/// towards the mask even when the silhouettes do not overlap at the start.
/// Applies when the phase records the soft mask.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Barycenter;

impl Term for Barycenter {
    fn name(&self) -> &str {
        "barycenter"
    }

    fn evaluate<'t>(&self, ctx: &TermContext<'_, 't>) -> Result<Option<Var<'t, f64>>> {
        let Some(soft) = ctx.soft_mask else { return Ok(None) };
        let (x, y) = soft.barycenter();
        let reference = ctx.reference.barycenter();
        let inv_diagonal = 1.0 / ctx.diagonal_px();
        let dx = (x - reference.x) * inv_diagonal;
        let dy = (y - reference.y) * inv_diagonal;
        Ok(Some(dx * dx + dy * dy))
    }
}

/// Distance of the probe's orientation to the canonical front-facing one,
/// `1 - (q . q_ref)^2`: zero for both signs of the same rotation (q and -q),
/// 1 for a half turn. Stops the upside-down minima of symmetric probes.
/// Always applies.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct OrientationPrior;

impl OrientationPrior {
    /// The prior towards [`TermContext::front_facing`].
    pub fn front_facing() -> Self {
        OrientationPrior
    }
}

impl Term for OrientationPrior {
    fn name(&self) -> &str {
        "orientation"
    }

    fn evaluate<'t>(&self, ctx: &TermContext<'_, 't>) -> Result<Option<Var<'t, f64>>> {
        let (q, r) = (ctx.pose.rotation, ctx.front_facing);
        let dot = q.w * r.w as f64 + q.v.x * r.x as f64 + q.v.y * r.y as f64 + q.v.z * r.z as f64;
        Ok(Some((dot * dot).rsub(1.0)))
    }
}
