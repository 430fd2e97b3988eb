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

use super::lighting::{
    FitRequest, LightingFit, LightingPurpose, Smoothness, env_from_texels, fit_lighting, lighting_report,
};
use super::photo::{Photo, Pixels};
use super::ranking::{best_ranked, mean_rgb_angle_deg, renders_alike, rival_starts};
use super::report::{AxisReport, PhaseLog, PhaseReport, StartReport};
use super::settings::Settings;
use super::silhouette::{
    PoseContext, PoseSteps, fit_pose_to_image, fit_silhouette, polish_silhouette, refit_silhouette, silhouette_loss,
};
use super::{Probe, hypotheses};
use crate::error::{Error, Result};
use crate::objective::mask_mean_luminance;

/// What the pose search found: the pose, every axis hypothesis's and
/// start's account and the index of the start kept.
pub(super) struct PoseSearch {
    pub(super) pose: Pose,
    /// The chosen pose's rivals, which the photo judges: for a probe
    /// symmetric about its axis, the other end's best outline fit, if it
    /// fits within `OrientationSettings::rival_end_ratio`; for one with a pattern, see
    /// [`rival_starts`].
    pub(super) rivals: Vec<Pose>,
    pub(super) axes: Vec<AxisReport>,
    pub(super) starts: Vec<StartReport>,
    pub(super) chosen: usize,
    /// Whether the probe rendered alike turned about its axis (no pattern).
    pub(super) symmetric: bool,
}

/// A start's refit (if any), ranking phase, account and pose.
pub(super) type RankedStart = (Option<PhaseReport>, PhaseReport, StartReport, Pose);

/// Logs ranked starts in order and keeps their accounts and poses.
pub(super) fn record(
    ranked: Vec<Result<RankedStart>>,
    phases: &mut PhaseLog,
    starts: &mut Vec<StartReport>,
    candidates: &mut Vec<Pose>,
) -> Result<()> {
    for result in ranked {
        let (refit, ranking, account, pose) = result?;
        if let Some(refit) = refit {
            phases.expect_more(1);
            phases.push(refit);
        }
        phases.push(ranking);
        starts.push(account);
        candidates.push(pose);
    }
    Ok(())
}

/// The pose search (see the module's description): axis hypotheses by
/// silhouette, their turns ranked by re-rendering colour error, then
/// alternation of pose and lighting from the best start.
pub(super) fn search_pose(
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
    // The objective's smoothness weight (applied by the linear solve) while
    // the pose is searched: a detailed map would explain a misplaced texture
    // away (texture baked into the light) and hide the pose error from the
    // image loss. The final solve uses the settings' (weaker) smoothness.
    let search_smoothness = settings.objective.smoothness_weight(1.0).unwrap_or(0.0);
    let ranking_render = RenderSettings {
        spp: o.ranking_spp,
        seed: settings.seed,
    };
    let mesh = &probe.asset.mesh;
    let shape = hypotheses::MaskShape::new(&photo.mask)?;
    let hypotheses = hypotheses::axis_hypotheses(&photo.camera, &shape, mesh, probe.top_known, &settings.hypotheses);
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
            fit_silhouette(
                &ctx,
                "silhouette",
                start,
                (settings.outline.iters, PoseSteps::Full),
                progress,
                settings.seed,
            )
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
    // (`hypotheses::outline_twins`) are hypotheses too, fitted likewise.
    let best_fit = axis_poses.iter().map(|(_, loss)| *loss).fold(f64::INFINITY, f64::min);
    let cos_same = o.same_fitted_axis_deg.to_radians().cos();
    let mut twins: Vec<(usize, Pose)> = Vec::new();
    for (a, (pose, loss)) in axis_poses.iter().enumerate() {
        if *loss > o.axis_keep_ratio * best_fit {
            continue;
        }
        for twin in hypotheses::outline_twins(pose, mesh, &photo.camera, &settings.hypotheses) {
            let axis = twin.rotation * Vec3::Y;
            let distinct = axis_poses
                .iter()
                .map(|(p, _)| p)
                .chain(twins.iter().map(|(_, p)| p))
                .all(|p| (p.rotation * Vec3::Y).dot(axis) < cos_same);
            if distinct {
                twins.push((a, twin));
            }
        }
    }
    phases.expect_more(twins.len());
    let fitted: Vec<Result<_>> = twins
        .par_iter()
        .map(|&(_, twin)| refit_silhouette(&ctx, "silhouette_twin", twin, settings))
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
    phases.expect_more((kept.len() - 1) * o.starts_deg.len());
    // One start: the turned pose, refitted to the silhouette if the turn
    // changed it, then ranked.
    let rank_turn = |a: usize, yaw: f32, refinement: bool| -> Result<RankedStart> {
        let (axis_pose, axis_loss) = axis_poses[a];
        let turned = hypotheses::turned(&axis_pose, mesh, yaw);
        let loss = silhouette_loss(&ctx, &turned, settings.seed)?;
        let (pose, loss, refit) = if loss > o.turn_refit_ratio * axis_loss {
            let (pose, loss, report) = refit_silhouette(&ctx, "silhouette_turn", turned, settings)?;
            (pose, loss, Some(report))
        } else {
            (turned, loss, None)
        };
        let t1 = Instant::now();
        // Ranked under a coarse, smooth map: a wrong orientation puts the
        // probe's texture in the wrong place, which only a detailed map
        // could explain away (texture baked into the light).
        let coarse = fit_lighting(
            probe,
            photo,
            clipped,
            &pose,
            &FitRequest {
                size: o.ranking_size,
                render: ranking_render,
                sampling: LightSampling::BSDF,
                smoothness: Smoothness::quadratic(o.ranking_smoothness),
                purpose: LightingPurpose::Search,
                pixels: Pixels::All,
                start: None,
                max_iters: settings.lighting.solve_iters,
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
            rgb_angle_deg: mean_rgb_angle_deg(&coarse.rendered, &coarse.target, &coarse.weight),
            relative_error: coarse.weighted_sq_error(),
        };
        Ok((refit, ranking, account, pose))
    };
    let mut starts = Vec::new();
    let mut candidates = Vec::new();
    // A probe symmetric about its axis (a cap of one colour) renders alike
    // at every turn: its asset tells, or else two turns of the first axis
    // do, and then one turn per axis is all there is to rank, and no yaw to
    // refine.
    let tells = o.starts_deg.len().min(2);
    let first: Vec<(usize, f32)> = o.starts_deg[..tells].iter().map(|&yaw| (kept[0], yaw)).collect();
    record(
        first.par_iter().map(|&(a, yaw)| rank_turn(a, yaw, false)).collect(),
        phases,
        &mut starts,
        &mut candidates,
    )?;
    let symmetric = match probe.alike_turned {
        Some(alike) => alike,
        None => tells == 2 && renders_alike(&starts[0], &starts[1], o),
    };
    let rest: Vec<(usize, f32)> = kept
        .iter()
        .enumerate()
        .flat_map(|(k, &a)| {
            let yaws = match (k, symmetric) {
                (0, true) => &[][..],
                (0, false) => &o.starts_deg[tells..],
                (_, true) => &o.starts_deg[..1],
                (_, false) => &o.starts_deg[..],
            };
            yaws.iter().map(move |&yaw| (a, yaw))
        })
        .collect();
    phases.expect_fewer(kept.len() * o.starts_deg.len() - first.len() - rest.len());
    record(
        rest.par_iter().map(|&(a, yaw)| rank_turn(a, yaw, false)).collect(),
        phases,
        &mut starts,
        &mut candidates,
    )?;
    // A start's yaw refined by halving steps about it (the starts are a
    // coarse grid; the image loss alone pulls a turn in only slowly).
    let first_step = match symmetric {
        true => 0.0,
        false => 180.0 / o.starts_deg.len() as f32,
    };
    let mut refine = |mut best: usize, starts: &mut Vec<StartReport>, candidates: &mut Vec<Pose>| -> Result<usize> {
        let mut step = first_step;
        while step >= o.yaw_refine_deg {
            let (a, yaw) = (starts[best].axis, starts[best].yaw_deg);
            phases.expect_more(2);
            let ranked = [yaw - step, yaw + step]
                .par_iter()
                .map(|&y| rank_turn(a, y, true))
                .collect();
            let tried = starts.len();
            record(ranked, phases, starts, candidates)?;
            best = best_ranked(starts, std::iter::once(best).chain(tried..starts.len()), symmetric, o).unwrap_or(best);
            step *= 0.5;
        }
        Ok(best)
    };
    // Colour ranks the starts of a probe with a pattern. A probe symmetric
    // about its axis shows none: a coarse map explains it about as well
    // either end up (a lying cap of one colour: 7.76 deg upside down, 7.82
    // the right way up), and the starts go by their outlines (at default
    // quality the least silhouette loss was within 1 deg of the true axis
    // on all 9 cap scenes of the suite). Their margin between a cap's ends can be small: on
    // the lying courtyard cap the two ends' silhouette losses are 1.6 %
    // apart (38 % under SoftRas, whose limb bias made much of it), and the
    // suite's default run took the right end, its fast run the wrong one.
    let best = best_ranked(&starts, 0..starts.len(), symmetric, o).expect("at least one start");
    let chosen = refine(best, &mut starts, &mut candidates)?;
    let axis = candidates[chosen].rotation * Vec3::Y;
    let rivals = match symmetric {
        true => axis_poses
            .iter()
            .filter(|(p, loss)| {
                (p.rotation * Vec3::Y).dot(axis) < 0.0 && *loss <= o.rival_end_ratio * starts[chosen].silhouette_loss
            })
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(p, _)| *p)
            .into_iter()
            .collect(),
        false => {
            let mut rivals = Vec::new();
            for k in rival_starts(&starts, &candidates, chosen, o) {
                let refined = refine(k, &mut starts, &mut candidates)?;
                rivals.push(candidates[refined]);
            }
            rivals
        }
    };
    // The rivals polished as the chosen pose is, for a fair test (side by
    // side, as the axes' fits run).
    let polished: Vec<_> = std::iter::once(candidates[chosen])
        .chain(rivals)
        .collect::<Vec<_>>()
        .into_par_iter()
        .map(|pose| polish_silhouette(&ctx, pose, settings))
        .collect();
    let mut polished = polished.into_iter();
    let (mut pose, report) = polished.next().expect("the chosen pose")?;
    phases.expect_more(1);
    phases.push(report);
    let mut rivals = Vec::new();
    for result in polished {
        let (rival, report) = result?;
        phases.expect_more(1);
        phases.push(report);
        rivals.push(rival);
    }
    let depth = (pose.translation - photo.camera.origin).length();
    // The search-resolution map, from `start` (or from scratch), reported.
    let joint_render = RenderSettings {
        spp: settings.joint.spp,
        seed: settings.seed,
    };
    let search_lighting = |pose: &Pose, start: Option<&[f64]>, phases: &mut PhaseLog| -> Result<LightingFit> {
        let t1 = Instant::now();
        let fit = fit_lighting(
            probe,
            photo,
            clipped,
            pose,
            &FitRequest {
                size: work,
                render: joint_render,
                sampling: LightSampling::BSDF,
                smoothness: Smoothness::quadratic(search_smoothness),
                purpose: LightingPurpose::Search,
                pixels: Pixels::All,
                start,
                max_iters: settings.lighting.solve_iters,
            },
            &settings.lighting,
        )?;
        phases.push(lighting_report("lighting", &fit, t1));
        Ok(fit)
    };
    if settings.joint.rounds > 0 {
        let mut fit = search_lighting(&pose, None, phases)?;
        for round in 0..settings.joint.rounds {
            let env = env_from_texels(&fit.env, work.0, work.1)?;
            let (new_pose, report) = fit_pose_to_image(&ctx, pose, &env, settings, depth, round)?;
            phases.push(report);
            pose = new_pose;
            if round + 1 == settings.joint.rounds {
                // The output's own solve follows.
                break;
            }
            fit = search_lighting(&pose, Some(&fit.env), phases)?;
        }
    }
    Ok(PoseSearch {
        pose,
        rivals,
        axes,
        starts,
        chosen,
        symmetric,
    })
}
