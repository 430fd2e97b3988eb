//! The pose stages of the estimate: axis hypotheses from the mask
//! ([`hypotheses`]), each fitted to the outline ([`silhouette`]); the kept
//! axes' turns ranked by colour ([`ranking`]) and by the label's shading
//! ([`shading`]), put together in [`orientation`]; then what only the photo
//! tells -- the size, the lean, the chosen pose against its rivals, a small
//! probe's refinement -- in [`judgement`].

pub mod hypotheses;
pub mod judgement;
pub mod orientation;
pub mod ranking;
pub mod shading;
pub mod silhouette;
