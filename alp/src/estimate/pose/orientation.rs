//! The orientation search, in two stages. *Axes*: where the probe's axis
//! points is hypothesised from the mask ([`hypotheses::axis_hypotheses`]),
//! each hypothesis fitted to the outline ([`silhouette`](super::silhouette)),
//! with the outline's look-alikes of each good fit
//! ([`hypotheses::outline_twins`]); the axes that fit best go on. *Turns*:
//! each kept axis turned about itself by the yaw starts, each start ranked
//! by colour under a coarse map ([`ranking`](super::ranking)), the best
//! start's yaw refined by halving steps. Out come the chosen pose, polished
//! on to the outline's optimum, and its rivals, for the photo to judge.

use std::time::Instant;

use glam::Vec3;
use rayon::prelude::*;
use render::integrator::{LightSampling, RenderSettings};
use render::pose::Pose;
use render::silhouette::ReferenceMask;

use super::hypotheses;
use super::ranking::{best_ranked, mean_rgb_angle_deg, renders_alike, rival_starts};
use super::shading::LabelVariation;
use super::silhouette::{
    PoseContext, PoseSteps, fit_pose_to_image, fit_silhouette, polish_silhouette, refit_silhouette, silhouette_loss,
};
use crate::error::{Error, Result};
use crate::estimate::Probe;
use crate::estimate::lighting::{
    FitRequest, LightingFit, LightingPurpose, LightingTerms, env_from_texels, fit_lighting, lighting_report,
};
use crate::estimate::photo::{Photo, Pixels};
use crate::estimate::report::{AxisReport, PhaseLog, PhaseReport, PoseRecord, StartReport, resident_mb};
use crate::estimate::settings::{OrientationSettings, Settings};
use crate::objective::mask_mean_luminance;

/// What the pose search found: the pose, every axis hypothesis's and
/// start's account and the index of the start kept.
pub(in crate::estimate) struct PoseSearch {
    pub(in crate::estimate) pose: Pose,
    /// The chosen pose's rivals, which the photo judges: for a probe
    /// symmetric about its axis, the other end's best outline fit, if it
    /// fits within `OrientationSettings::rival_end_ratio`; for one with a pattern, see
    /// [`rival_starts`].
    pub(in crate::estimate) rivals: Vec<Pose>,
    pub(in crate::estimate) axes: Vec<AxisReport>,
    pub(in crate::estimate) starts: Vec<StartReport>,
    pub(in crate::estimate) chosen: usize,
    /// Whether the probe rendered alike turned about its axis (no pattern).
    pub(in crate::estimate) symmetric: bool,
}

impl PoseSearch {
    /// The accounts the report keeps: every axis, every start, the one chosen.
    pub(in crate::estimate) fn into_accounts(self) -> (Vec<AxisReport>, Vec<StartReport>, Option<usize>) {
        (self.axes, self.starts, Some(self.chosen))
    }
}

/// A start's refit (if any), ranking phase, account and pose.
type RankedStart = (Option<PhaseReport>, PhaseReport, StartReport, Pose);

/// The pose search (see the module's description): axis hypotheses by
/// silhouette, their turns ranked by re-rendering colour error, the chosen
/// pose and its rivals polished; on request, joint rounds of pose and
/// lighting from the chosen pose.
pub(in crate::estimate) fn search_pose(
    probe: &Probe,
    photo: &Photo,
    reference: &ReferenceMask,
    clipped: &[bool],
    work: (usize, usize),
    settings: &Settings,
    phases: &mut PhaseLog,
) -> Result<PoseSearch> {
    let ctx = PoseContext {
        probe,
        photo,
        reference,
        objective: &settings.objective,
        front_facing: hypotheses::front_facing(&photo.camera),
        clipped,
        level: mask_mean_luminance(&photo.image, &photo.mask)?,
        outline: &settings.outline,
    };
    let o = &settings.orientation;
    if o.starts_deg.is_empty() {
        return Err(Error::invalid("starts", "at least one orientation start is needed"));
    }
    let (mut axes, axis_poses) = fit_axes(&ctx, settings, phases)?;
    let kept = keep_axes(&mut axes, o);
    phases.expect_more((kept.len() - 1) * o.starts_deg.len());
    let ranker = Ranker {
        ctx: &ctx,
        settings,
        axis_poses: &axis_poses,
    };
    let ranked = ranker.rank(&kept, phases)?;
    let chosen_pose = ranked.poses[ranked.chosen];
    let (pose, rivals) = polish(&ctx, chosen_pose, ranked.rivals, settings, phases)?;
    let pose = joint_rounds(&ctx, pose, work, settings, phases)?;
    Ok(PoseSearch {
        pose,
        rivals,
        axes,
        starts: ranked.reports,
        chosen: ranked.chosen,
        symmetric: ranked.symmetric,
    })
}

/// Each axis hypothesis's account, and its fitted pose and silhouette loss.
type AxisFits = (Vec<AxisReport>, Vec<(Pose, f64)>);

/// Every axis hypothesis fitted to the outline (at several turns for a
/// probe whose outline a turn changes, the best kept), then the outline
/// twins of each that fits, fitted likewise: each axis's account, pose and
/// silhouette loss.
fn fit_axes(ctx: &PoseContext, settings: &Settings, phases: &mut PhaseLog) -> Result<AxisFits> {
    let (probe, photo, o) = (ctx.probe, ctx.photo, &settings.orientation);
    let mesh = &probe.asset.mesh;
    let shape = hypotheses::MaskShape::new(&photo.mask)?;
    let grid = hypotheses::OutlineGrid::new(&photo.mask, &shape, settings.hypotheses.outline_cells);
    let hypotheses: Vec<Vec3> = hypotheses::axis_hypotheses(&photo.camera, &shape, &grid, mesh, &settings.hypotheses)
        .into_iter()
        .map(|(axis, _)| axis)
        .collect();
    // A probe whose outline a turn changes (a mug's handle) fits each axis
    // at several turns, the best kept: a fit from one turn pulls the axis
    // after a handle where the photo shows none.
    let turns: &[f32] = match probe.turns_show {
        true => &o.axis_fit_turns_deg,
        false => &[0.0],
    };
    phases.expect_more(hypotheses.len() * turns.len() - 1);
    // Hypotheses and starts are independent and each one's small pose tapes
    // keep about one core busy: they run side by side (results do not
    // depend on the thread count; reports keep their order).
    let fitted: Vec<Result<_>> = hypotheses
        .par_iter()
        .flat_map_iter(|&axis| {
            let start = hypotheses::initial_pose(mesh, &photo.camera, &shape, axis);
            // (Unturned, the start is the one a probe of revolution has.)
            turns.iter().map(move |&turn| match turn == 0.0 {
                true => start,
                false => hypotheses::turned(&start, mesh, turn),
            })
        })
        .map(|start| {
            let progress = 0.0..settings.outline.progress;
            let iters = (settings.outline.iters, PoseSteps::Full);
            fit_silhouette(ctx, "silhouette", start, iters, progress, settings.seed)
        })
        .collect();
    let mut axes = Vec::new();
    let mut axis_poses = Vec::new();
    let mut fitted = fitted.into_iter();
    for axis in &hypotheses {
        let mut best: Option<(Pose, f64)> = None;
        for _ in turns {
            let (pose, loss, report) = fitted.next().expect("a fit per axis and turn")?;
            phases.push(report);
            if best.is_none_or(|(_, least)| loss < least) {
                best = Some((pose, loss));
            }
        }
        let (pose, loss) = best.expect("at least one turn");
        axes.push(AxisReport {
            axis: axis.to_array(),
            fitted_axis: (pose.rotation * Vec3::Y).to_array(),
            silhouette_loss: loss,
            twin_of: None,
            kept: false,
        });
        axis_poses.push((pose, loss));
    }
    // The outline does not tell an axis leaning towards the camera from
    // one leaning as far away, nor (where the probe's ends have like
    // outlines) which end is which, and a fit stops on whichever is nearest
    // its start: the outline twins of each axis whose outline fits
    // (`hypotheses::outline_twins`) are hypotheses too, fitted likewise --
    // unless an axis already there fits as well (a fit from the sphere's
    // start on the twin's axis may have stopped in a poorer minimum).
    let best_fit = axis_poses.iter().map(|(_, loss)| *loss).fold(f64::INFINITY, f64::min);
    let cos_same = o.same_fitted_axis_deg.to_radians().cos();
    let mut twins: Vec<(usize, Pose)> = Vec::new();
    for (a, (pose, loss)) in axis_poses.iter().enumerate() {
        if *loss > o.axis_keep_ratio * best_fit {
            continue;
        }
        for twin in hypotheses::outline_twins(pose, mesh, &photo.camera, &settings.hypotheses) {
            let axis = twin.rotation * Vec3::Y;
            if twin_is_new(axis, &axis_poses, &twins, cos_same, o.axis_keep_ratio * best_fit) {
                twins.push((a, twin));
            }
        }
    }
    phases.expect_more(twins.len());
    let fitted: Vec<Result<_>> = twins
        .par_iter()
        .map(|&(_, twin)| refit_silhouette(ctx, "silhouette_twin", twin, settings))
        .collect();
    for (result, (a, twin)) in fitted.into_iter().zip(twins) {
        let (pose, loss, report) = result?;
        phases.push(report);
        axes.push(AxisReport {
            axis: (twin.rotation * Vec3::Y).to_array(),
            fitted_axis: (pose.rotation * Vec3::Y).to_array(),
            silhouette_loss: loss,
            twin_of: Some(a),
            kept: false,
        });
        axis_poses.push((pose, loss));
    }
    Ok((axes, axis_poses))
}

/// Whether an outline twin on `axis` is a new hypothesis: no axis fitted
/// on it has a silhouette loss within `good` (a fit from the sphere's start
/// there may have stopped in a poorer minimum than the twin's), and no twin
/// on it is there yet. Axes closer than `cos_same` (a cosine) are one.
fn twin_is_new(axis: Vec3, axis_poses: &[(Pose, f64)], twins: &[(usize, Pose)], cos_same: f32, good: f64) -> bool {
    let on_axis = |p: &Pose| (p.rotation * Vec3::Y).dot(axis) >= cos_same;
    axis_poses.iter().all(|(p, loss)| !(on_axis(p) && *loss <= good)) && twins.iter().all(|(_, p)| !on_axis(p))
}

/// The axes whose turns are ranked: the best-fitting distinct ones, at most
/// `OrientationSettings::axes_kept`, within `axis_keep_ratio` of the best
/// (marked kept in their accounts), best first.
fn keep_axes(axes: &mut [AxisReport], o: &OrientationSettings) -> Vec<usize> {
    let mut order: Vec<usize> = (0..axes.len()).collect();
    order.sort_by(|&a, &b| axes[a].silhouette_loss.total_cmp(&axes[b].silhouette_loss));
    let best_loss = axes[order[0]].silhouette_loss;
    let cos_same = o.same_fitted_axis_deg.to_radians().cos();
    let mut kept: Vec<usize> = Vec::new();
    for &a in &order {
        let axis = Vec3::from_array(axes[a].fitted_axis);
        let distinct = kept
            .iter()
            .all(|&k| Vec3::from_array(axes[k].fitted_axis).dot(axis) < cos_same);
        if kept.len() < o.axes_kept.max(1) && axes[a].silhouette_loss <= o.axis_keep_ratio * best_loss && distinct {
            kept.push(a);
        }
    }
    kept.iter().for_each(|&k| axes[k].kept = true);
    kept
}

/// The ranked starts: each one's account and pose, in the order ranked.
#[derive(Default)]
struct Starts {
    reports: Vec<StartReport>,
    poses: Vec<Pose>,
}

impl Starts {
    /// Logs ranked starts in order and keeps their accounts and poses.
    fn record(&mut self, ranked: Vec<Result<RankedStart>>, phases: &mut PhaseLog) -> Result<()> {
        for result in ranked {
            let (refit, ranking, account, pose) = result?;
            if let Some(refit) = refit {
                phases.expect_more(1);
                phases.push(refit);
            }
            phases.push(ranking);
            self.reports.push(account);
            self.poses.push(pose);
        }
        Ok(())
    }
}

/// What the ranking chose: every start, the chosen one, its rivals, and
/// whether the probe rendered alike turned.
struct Ranked {
    reports: Vec<StartReport>,
    poses: Vec<Pose>,
    chosen: usize,
    rivals: Vec<Pose>,
    symmetric: bool,
}

/// Turns of the fitted axes, ranked by colour.
struct Ranker<'a> {
    ctx: &'a PoseContext<'a>,
    settings: &'a Settings,
    /// Each axis's fitted pose and silhouette loss.
    axis_poses: &'a [(Pose, f64)],
}

impl Ranker<'_> {
    /// The starts of the `kept` axes ranked: the first axis's first two
    /// turns tell whether the probe renders alike turned (unless the asset
    /// tells), then every other start; the best one's yaw refined, and its
    /// rivals found.
    fn rank(&self, kept: &[usize], phases: &mut PhaseLog) -> Result<Ranked> {
        let o = &self.settings.orientation;
        let mut starts = Starts::default();
        // A probe that shows no pattern turned (a cap of one colour) renders
        // alike at every turn: its asset tells, or else two turns of the
        // first axis do, and then one turn per axis is all there is to rank
        // (the fitted one, where the asset tells), and no yaw to refine.
        let known = self.ctx.probe.alike_turned;
        let tells = match known {
            Some(_) => 0,
            None => o.starts_deg.len().min(2),
        };
        let first: Vec<(usize, f32)> = o.starts_deg[..tells].iter().map(|&yaw| (kept[0], yaw)).collect();
        starts.record(self.rank_all(&first, false), phases)?;
        let symmetric = match known {
            Some(alike) => alike,
            None => tells == 2 && renders_alike(&starts.reports[0], &starts.reports[1], o),
        };
        let rest: Vec<(usize, f32)> = kept
            .iter()
            .enumerate()
            .flat_map(|(k, &a)| {
                let yaws = match (symmetric, k == 0 && tells > 0) {
                    (true, true) => &[][..],
                    (true, false) => &[0.0][..],
                    (false, true) => &o.starts_deg[tells..],
                    (false, false) => &o.starts_deg[..],
                };
                yaws.iter().map(move |&yaw| (a, yaw))
            })
            .collect();
        phases.expect_fewer(kept.len() * o.starts_deg.len() - first.len() - rest.len());
        starts.record(self.rank_all(&rest, false), phases)?;
        // Colour ranks the starts of a probe with a pattern. A probe symmetric
        // about its axis shows none: a coarse map explains it about as well
        // either end up, and the starts go by their outlines.
        let best = best_ranked(&starts.reports, 0..starts.reports.len(), symmetric, o).expect("at least one start");
        // A probe with a pattern of colours takes the turn its shading tells
        // (lighting-free), scanned round the whole circle from the best
        // start: no yaw to refine by colour first. The photo then judges
        // only its other end.
        let label = match !symmetric && self.ctx.probe.colours_alike != Some(true) {
            true => Some(LabelVariation::new(
                self.ctx.probe,
                self.ctx.photo,
                self.ctx.clipped,
                o,
            )?),
            false => None,
        };
        let chosen = match &label {
            Some(label) => self.turn_by_label(label, best, &mut starts, phases)?,
            None => self.refine_yaw(best, symmetric, &mut starts, phases)?,
        };
        let axis = starts.poses[chosen].rotation * Vec3::Y;
        let rivals = match symmetric {
            true => self
                .axis_poses
                .iter()
                .filter(|(p, loss)| {
                    let chosen_loss = starts.reports[chosen].silhouette_loss;
                    (p.rotation * Vec3::Y).dot(axis) < 0.0 && *loss <= o.rival_end_ratio * chosen_loss
                })
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .map(|(p, _)| *p)
                .into_iter()
                .collect(),
            false => {
                let mut rivals = Vec::new();
                let colours_alike = self.ctx.probe.colours_alike == Some(true);
                for k in rival_starts(&starts.reports, &starts.poses, chosen, colours_alike, o) {
                    let refined = match &label {
                        Some(_) if (starts.poses[k].rotation * Vec3::Y).dot(axis) > 0.0 => continue,
                        Some(label) => self.turn_by_label(label, k, &mut starts, phases)?,
                        None => self.refine_yaw(k, symmetric, &mut starts, phases)?,
                    };
                    rivals.push(starts.poses[refined]);
                }
                rivals
            }
        };
        Ok(Ranked {
            reports: starts.reports,
            poses: starts.poses,
            chosen,
            rivals,
            symmetric,
        })
    }

    /// Start `best`'s yaw refined by halving steps about it (the starts are
    /// a coarse grid; the image loss alone pulls a turn in only slowly);
    /// none for a `symmetric` probe. Returns the best start.
    fn refine_yaw(
        &self,
        mut best: usize,
        symmetric: bool,
        starts: &mut Starts,
        phases: &mut PhaseLog,
    ) -> Result<usize> {
        let o = &self.settings.orientation;
        let mut step = match symmetric {
            true => 0.0,
            false => 180.0 / o.starts_deg.len() as f32,
        };
        while step >= o.yaw_refine_deg {
            let (a, yaw) = (starts.reports[best].axis, starts.reports[best].yaw_deg);
            phases.expect_more(2);
            let tried = starts.reports.len();
            starts.record(self.rank_all(&[(a, yaw - step), (a, yaw + step)], true), phases)?;
            let among = std::iter::once(best).chain(tried..starts.reports.len());
            best = best_ranked(&starts.reports, among, symmetric, o).unwrap_or(best);
            step *= 0.5;
        }
        Ok(best)
    }

    /// Start `k` turned about its axis to the turn of least label variation
    /// (a new start, ranked), or `k` itself when that is its own turn.
    fn turn_by_label(
        &self,
        label: &LabelVariation,
        k: usize,
        starts: &mut Starts,
        phases: &mut PhaseLog,
    ) -> Result<usize> {
        let o = &self.settings.orientation;
        let t0 = Instant::now();
        let found = label.best_turn(&starts.poses[k], o);
        let mesh = &self.ctx.probe.asset.mesh;
        phases.expect_more(1);
        phases.push(PhaseReport {
            name: "label_turn".into(),
            iterations: 0,
            evaluations: found.scored,
            wall_s: t0.elapsed().as_secs_f64(),
            loss: [("label_variation".to_string(), found.variation)].into(),
            per_iteration: Vec::new(),
            psnr_db: None,
            pose: Some(PoseRecord::from(&hypotheses::turned(
                &starts.poses[k],
                mesh,
                found.turn,
            ))),
            termination: None,
            resident_mb: resident_mb(),
        });
        let turn = (found.turn + 180.0).rem_euclid(360.0) - 180.0;
        if turn.abs() < o.yaw_refine_deg {
            return Ok(k);
        }
        let (a, yaw) = (starts.reports[k].axis, starts.reports[k].yaw_deg);
        phases.expect_more(1);
        let tried = starts.reports.len();
        starts.record(self.rank_all(&[(a, yaw + turn)], true), phases)?;
        Ok(tried)
    }

    /// The turns `(axis, yaw)` ranked side by side, in order.
    fn rank_all(&self, turns: &[(usize, f32)], refinement: bool) -> Vec<Result<RankedStart>> {
        turns
            .par_iter()
            .map(|&(a, yaw)| self.rank_turn(a, yaw, refinement))
            .collect()
    }

    /// One start: axis `a`'s pose turned by `yaw`, refitted to the
    /// silhouette if the turn changed it, then ranked under a coarse, smooth
    /// map: a wrong orientation puts the probe's texture in the wrong place,
    /// which only a detailed map could explain away (texture baked into the
    /// light).
    fn rank_turn(&self, a: usize, yaw: f32, refinement: bool) -> Result<RankedStart> {
        let (ctx, settings, o) = (self.ctx, self.settings, &self.settings.orientation);
        let (axis_pose, axis_loss) = self.axis_poses[a];
        let turned = hypotheses::turned(&axis_pose, &ctx.probe.asset.mesh, yaw);
        let loss = silhouette_loss(ctx, &turned, settings.seed)?;
        let (pose, loss, refit) = if loss > o.turn_refit_ratio * axis_loss {
            let (pose, loss, report) = refit_silhouette(ctx, "silhouette_turn", turned, settings)?;
            (pose, loss, Some(report))
        } else {
            (turned, loss, None)
        };
        let t1 = Instant::now();
        let terms = LightingTerms::quadratic(o.ranking_smoothness, settings.lighting.method)?;
        let coarse = fit_lighting(
            ctx.probe,
            ctx.photo,
            ctx.clipped,
            &pose,
            &FitRequest {
                size: o.ranking_size,
                render: RenderSettings {
                    spp: o.ranking_spp,
                    seed: settings.seed,
                },
                sampling: LightSampling::BSDF,
                terms: &terms,
                purpose: LightingPurpose::Search,
                pixels: Pixels::All,
                start: None,
                max_iters: settings.lighting.solve_iters,
                term_values: false,
            },
            &settings.lighting,
        )?;
        let ranking = lighting_report("lighting_ranking", &coarse, t1);
        let account = StartReport {
            axis: a,
            yaw_deg: yaw,
            refinement,
            silhouette_loss: loss,
            refitted: refit.is_some(),
            psnr_db: coarse.psnr_db(),
            rgb_angle_deg: mean_rgb_angle_deg(&coarse.rendered, &coarse.data.target, &coarse.data.weight),
            relative_error: coarse.weighted_sq_error(),
        };
        Ok((refit, ranking, account, pose))
    }
}

/// The chosen pose and its rivals polished on to the outline's optimum,
/// side by side (the rivals as the chosen pose is, for a fair test).
fn polish(
    ctx: &PoseContext,
    chosen: Pose,
    rivals: Vec<Pose>,
    settings: &Settings,
    phases: &mut PhaseLog,
) -> Result<(Pose, Vec<Pose>)> {
    let polished: Vec<_> = std::iter::once(chosen)
        .chain(rivals)
        .collect::<Vec<_>>()
        .into_par_iter()
        .map(|pose| polish_silhouette(ctx, pose, settings))
        .collect();
    let mut polished = polished.into_iter();
    let (pose, report) = polished.next().expect("the chosen pose")?;
    phases.expect_more(1);
    phases.push(report);
    let mut rivals = Vec::new();
    for result in polished {
        let (rival, report) = result?;
        phases.expect_more(1);
        phases.push(report);
        rivals.push(rival);
    }
    Ok((pose, rivals))
}

/// `JointSettings::rounds` of the pose by Adam on the whole objective under
/// the map solved at the pose so far (at `work`), each followed by the map
/// at the new pose but the last (the output's own solve follows), at
/// `JointSettings::map_smoothness`.
fn joint_rounds(
    ctx: &PoseContext,
    mut pose: Pose,
    work: (usize, usize),
    settings: &Settings,
    phases: &mut PhaseLog,
) -> Result<Pose> {
    if settings.joint.rounds == 0 {
        return Ok(pose);
    }
    let terms = LightingTerms::quadratic(settings.joint.map_smoothness, settings.lighting.method)?;
    let depth = (pose.translation - ctx.photo.camera.origin).length();
    // The search-resolution map, from `start` (or from scratch), reported.
    let search_lighting = |pose: &Pose, start: Option<&[f64]>, phases: &mut PhaseLog| -> Result<LightingFit> {
        let t1 = Instant::now();
        let fit = fit_lighting(
            ctx.probe,
            ctx.photo,
            ctx.clipped,
            pose,
            &FitRequest {
                size: work,
                render: RenderSettings {
                    spp: settings.joint.spp,
                    seed: settings.seed,
                },
                sampling: LightSampling::BSDF,
                terms: &terms,
                purpose: LightingPurpose::Search,
                pixels: Pixels::All,
                start,
                max_iters: settings.lighting.solve_iters,
                term_values: false,
            },
            &settings.lighting,
        )?;
        phases.push(lighting_report("lighting", &fit, t1));
        Ok(fit)
    };
    let mut fit = search_lighting(&pose, None, phases)?;
    for round in 0..settings.joint.rounds {
        let env = env_from_texels(&fit.env, work.0, work.1)?;
        let (new_pose, report) = fit_pose_to_image(ctx, pose, &env, settings, depth, round)?;
        phases.push(report);
        pose = new_pose;
        if round + 1 == settings.joint.rounds {
            break;
        }
        fit = search_lighting(&pose, Some(&fit.env), phases)?;
    }
    Ok(pose)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Quat;

    #[test]
    fn a_twin_is_fitted_unless_its_axis_already_fits_well() {
        let tipped = |deg: f32| Pose::new(Quat::from_rotation_x(deg.to_radians()), 1.0, Vec3::ZERO);
        let axis = tipped(180.0).rotation * Vec3::Y;
        let cos_same = 5f32.to_radians().cos();
        // An axis 3 deg from the twin's, fitted within the margin: no new hypothesis.
        assert!(!twin_is_new(axis, &[(tipped(177.0), 1.2)], &[], cos_same, 1.5));
        // Fitted to a poorer minimum, 1.8 times the best: the twin is fitted.
        assert!(twin_is_new(axis, &[(tipped(177.0), 1.8)], &[], cos_same, 1.5));
        // An axis elsewhere does not count; a twin already there does.
        assert!(twin_is_new(axis, &[(tipped(150.0), 1.0)], &[], cos_same, 1.5));
        assert!(!twin_is_new(axis, &[], &[(0, tipped(179.0))], cos_same, 1.5));
    }
}
