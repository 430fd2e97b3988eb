//! The pose stages of the estimate: axis hypotheses from the mask
//! ([`hypotheses`]), each fitted to the outline ([`silhouette`]); the kept
//! axes' turns ranked by colour ([`ranking`]) and by the label's shading
//! ([`shading`]), put together in [`orientation`]; then what only the photo
//! tells -- the size, the lean, the chosen pose against its rivals, a small
//! probe's refinement -- in [`judgement`]. Together they are one
//! `PoseMethod`; `Settings::pose_method` selects which the estimate runs.

pub mod hypotheses;
pub mod judgement;
pub mod orientation;
pub mod ranking;
pub mod shading;
pub mod silhouette;
pub mod uncertainty;

use render::pose::Pose;
use render::silhouette::ReferenceMask;

use crate::error::Result;
use crate::estimate::Probe;
use crate::estimate::lighting::MapSizes;
use crate::estimate::photo::Photo;
use crate::estimate::report::PhaseLog;
use crate::estimate::settings::{PoseMethodName, Settings};
use judgement::{Judged, PhotoJudge};
use orientation::{PoseSearch, search_pose};

/// What a pose method is given: the probe, the photo as the estimate works
/// on it, its mask prepared for the outline losses, its clipped pixels,
/// the map sizes, the settings, and the pose when the user knows it.
pub(in crate::estimate) struct PoseInput<'a> {
    pub(in crate::estimate) probe: &'a Probe<'a>,
    pub(in crate::estimate) photo: &'a Photo,
    pub(in crate::estimate) reference: &'a ReferenceMask,
    pub(in crate::estimate) clipped: &'a [bool],
    pub(in crate::estimate) sizes: &'a MapSizes,
    pub(in crate::estimate) settings: &'a Settings,
    pub(in crate::estimate) known_pose: Option<Pose>,
}

/// What a pose method found: the pose judged by the photo with its pilot
/// map and accounts, and the search's accounts when it searched.
pub(in crate::estimate) struct PoseFound {
    pub(in crate::estimate) search: Option<PoseSearch>,
    pub(in crate::estimate) judged: Judged,
}

/// A way of finding the probe's pose in the photo. A second method
/// implements it, gets a [`PoseMethodName`] and is returned by
/// [`method`]: the pipeline (`estimate_with`) is not edited.
pub(in crate::estimate) trait PoseMethod {
    /// The pose of `input.probe` in `input.photo`, each phase logged in `phases`.
    fn find(&self, input: &PoseInput, phases: &mut PhaseLog) -> Result<PoseFound>;
}

/// The method `name` selects.
pub(in crate::estimate) fn method(name: PoseMethodName) -> &'static dyn PoseMethod {
    match name {
        PoseMethodName::OutlineThenPhoto => &OutlineThenPhoto,
    }
}

/// The method of the paper's pipeline as we built it: axis hypotheses fitted
/// to the outline and their turns ranked by colour ([`search_pose`]), then
/// what the outline cannot tell judged by the photo ([`PhotoJudge`]). A
/// known pose is only judged (its pilot map).
struct OutlineThenPhoto;

impl PoseMethod for OutlineThenPhoto {
    fn find(&self, input: &PoseInput, phases: &mut PhaseLog) -> Result<PoseFound> {
        let search = match input.known_pose {
            Some(_) => None,
            None => Some(search_pose(
                input.probe,
                input.photo,
                input.reference,
                input.clipped,
                input.sizes.search,
                input.settings,
                phases,
            )?),
        };
        let (pose, rivals, patterned) = match (&search, input.known_pose) {
            (Some(search), _) => (search.pose, search.rivals.clone(), !search.symmetric),
            (None, pose) => (pose.expect("a known pose"), Vec::new(), false),
        };
        let judge = PhotoJudge {
            probe: input.probe,
            photo: input.photo,
            clipped: input.clipped,
            work: input.sizes.search,
            settings: input.settings,
            searched: search.is_some(),
        };
        let judged = judge.judge(phases, pose, rivals, patterned)?;
        Ok(PoseFound { search, judged })
    }
}
