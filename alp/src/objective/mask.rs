//! `L_mask`: L1 on masks plus a Chamfer loss on masks, rendered soft mask
//! against the photo's (`render::silhouette`).

use autodiff::Var;

use super::{Input, Term, TermContext};
use crate::error::Result;

/// Mean absolute difference of the soft mask and the photo's mask over the
/// image. Applies when the phase records the soft mask.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MaskL1;

impl Term for MaskL1 {
    fn name(&self) -> &str {
        "mask_l1"
    }

    fn reads(&self) -> &'static [Input] {
        &[Input::SoftMask]
    }

    fn evaluate<'t>(&self, ctx: &TermContext<'_, 't>) -> Result<Option<Var<'t, f64>>> {
        Ok(ctx.soft_mask.map(|soft| soft.mask_l1(ctx.reference)).transpose()?)
    }
}

/// Symmetric Chamfer distance between the rendered and the photo's
/// silhouettes, in image diagonals (pixels per reference pixel divided by
/// the diagonal: the same weight works at any resolution). Unlike the L1 it
/// stays informative when the silhouettes do not overlap. Applies when the
/// phase records the soft mask.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Chamfer;

impl Term for Chamfer {
    fn name(&self) -> &str {
        "chamfer"
    }

    fn reads(&self) -> &'static [Input] {
        &[Input::SoftMask]
    }

    fn evaluate<'t>(&self, ctx: &TermContext<'_, 't>) -> Result<Option<Var<'t, f64>>> {
        let Some(soft) = ctx.soft_mask else { return Ok(None) };
        Ok(Some(soft.chamfer(ctx.reference)? * (1.0 / ctx.diagonal_px())))
    }
}
