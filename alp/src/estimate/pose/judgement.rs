//! The photo-scored pose searches: at a pose, the lighting solved from a
//! nearby pose's map (with MIS guided by it) and its data term's weighted
//! error score how well the pose explains the photo. Line searches over one
//! parameter of the pose at a time (the size, the lean towards the view
//! ray, the sway, the turn) and the rival test use that score; a probe small
//! in the photo is refined by rounds of them.

use std::time::Instant;

use glam::Vec3;
use render::camera::Camera;
use render::integrator::{LightSampling, RenderSettings};
use render::mesh::Mesh;
use render::pose::Pose;
use render::sampling::EnvSampler;

use super::hypotheses;
use crate::error::Result;
use crate::estimate::Probe;
use crate::estimate::lighting::{
    FitRequest, LightingFit, LightingPurpose, LightingTerms, env_from_texels, fit_lighting, lighting_report,
};
use crate::estimate::photo::{Photo, Pixels};
use crate::estimate::report::{LineSearchReport, PhaseLog, PhaseReport, PoseRecord, RefinementStep, RivalReport};
use crate::estimate::settings::Settings;
use crate::estimate::symmetry::SelfMap;

/// The lean (degrees) that maximises `score` within `reach` either way,
/// by a line search: leans of 0 and of `step` either way; while one side
/// rises, steps doubling that way; then the vertex of the parabola through
/// the best lean tried and its neighbours, where it is a maximum. A lean
/// that cannot be scored scores minus infinity. Returns every (lean,
/// score) tried, in order.
pub(in crate::estimate) fn line_search_max(
    step: f32,
    reach: f32,
    mut score: impl FnMut(f32) -> Result<f64>,
) -> Result<Vec<(f32, f64)>> {
    let mut tried = vec![(0.0, score(0.0)?), (-step, score(-step)?), (step, score(step)?)];
    let (centre, minus, plus) = (tried[0].1, tried[1].1, tried[2].1);
    if minus.max(plus) > centre {
        let (mut x, mut best) = match plus >= minus {
            true => (step, plus),
            false => (-step, minus),
        };
        while (2.0 * x).abs() <= reach {
            let next = score(2.0 * x)?;
            tried.push((2.0 * x, next));
            if next <= best {
                break;
            }
            (x, best) = (2.0 * x, next);
        }
    }
    let mut sorted = tried.clone();
    sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
    let top = (0..sorted.len()).fold(0, |b, k| if sorted[k].1 > sorted[b].1 { k } else { b });
    if top > 0 && top + 1 < sorted.len() {
        let ((x1, f1), (x2, f2), (x3, f3)) = (sorted[top - 1], sorted[top], sorted[top + 1]);
        let (a, b) = ((x2 - x1) as f64, (x2 - x3) as f64);
        let denominator = a * (f2 - f3) - b * (f2 - f1);
        // The best lean tried is above both neighbours: the parabola is
        // concave (unless a neighbour failed: no parabola then).
        if f1.is_finite() && f3.is_finite() && denominator.abs() > 0.0 {
            let vertex = x2 as f64 - 0.5 * (a * a * (f2 - f3) - b * b * (f2 - f1)) / denominator;
            let vertex = (vertex as f32).clamp(x1, x3);
            tried.push((vertex, score(vertex)?));
        }
    }
    Ok(tried)
}

/// A rival's score by the pose searches' measure and the map solved for it,
/// with its pilot map (an error where the photo cannot show it).
type ScoredRival = Result<((f64, Vec<f64>), Vec<f64>)>;

/// What the photo's judgement of the searched pose found.
pub(in crate::estimate) struct Judged {
    /// The pose kept.
    pub(in crate::estimate) pose: Pose,
    /// Its pilot map at the search resolution (None without a pilot).
    pub(in crate::estimate) pilot: Option<Vec<f64>>,
    pub(in crate::estimate) rival: Option<RivalReport>,
    pub(in crate::estimate) size: Option<LineSearchReport>,
    pub(in crate::estimate) lean: Option<LineSearchReport>,
    pub(in crate::estimate) refinement: Vec<RefinementStep>,
}

/// The pose kept so far: its pilot map (solved at `piloted`, which the
/// line searches' moves leave behind) and its score, when known.
struct Kept {
    pose: Pose,
    map: Vec<f64>,
    piloted: Pose,
    scored: Option<(f64, Vec<f64>)>,
}

/// What [`PhotoJudge::refine`] searches.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(in crate::estimate) enum Moves {
    /// The lean and the sway, and a `patterned` probe's turn, in rounds.
    All { patterned: bool },
    /// The turn alone, once.
    Turn,
}

/// Judges poses by the photo: what every photo-scored search shares.
pub(in crate::estimate) struct PhotoJudge<'a> {
    pub(in crate::estimate) probe: &'a Probe<'a>,
    pub(in crate::estimate) photo: &'a Photo,
    pub(in crate::estimate) clipped: &'a [bool],
    /// The searches' map size.
    pub(in crate::estimate) work: (usize, usize),
    pub(in crate::estimate) settings: &'a Settings,
    /// Whether the pose was searched (a known pose is only piloted).
    pub(in crate::estimate) searched: bool,
}

impl PhotoJudge<'_> {
    /// The searched `pose` and its `rivals` judged by the photo: the pilot
    /// map; on request the size line search (ahead of the rival test,
    /// whose rivals grow with it); the rival test; for a small probe the
    /// refinement, else the lean line search. Nothing but the pose when
    /// there is no pilot (`Settings::spp_pilot` 0).
    pub(in crate::estimate) fn judge(
        &self,
        phases: &mut PhaseLog,
        pose: Pose,
        mut rivals: Vec<Pose>,
        patterned: bool,
    ) -> Result<Judged> {
        if self.settings.lighting.spp_pilot == 0 {
            let (pilot, rival, size, lean) = (None, None, None, None);
            return Ok(Judged {
                pose,
                pilot,
                rival,
                size,
                lean,
                refinement: Vec::new(),
            });
        }
        let map = self.pilot(&pose, phases)?;
        let mut kept = Kept {
            pose,
            map,
            piloted: pose,
            scored: None,
        };
        let refine = self.searched && photo_refines(self.photo, self.settings);
        let mut refinement = Vec::new();
        // The size first, before the rival test: a mask a pixel too wide
        // or too narrow grows or shrinks the outline's pose, and the
        // probe's every normal with it, and the photo judges the ends
        // and turns of a probe of the wrong size. The rivals grow as the
        // chosen pose did.
        let radius_px = (self.photo.mask.count() as f32 / std::f32::consts::PI).sqrt();
        let mesh = &self.probe.asset.mesh;
        let grown = |pose: &Pose, px: f32| hypotheses::rescaled(pose, mesh, 1.0 + px / radius_px);
        let size_search = (
            self.settings.pose_search.size_step_px,
            self.settings.pose_search.size_reach_px,
        );
        let size = self.search(
            phases,
            &mut kept,
            "lighting_size",
            size_search,
            Pixels::Checkerboard,
            &grown,
        )?;
        kept.piloted = kept.pose;
        if let Some(size) = &size {
            rivals.iter_mut().for_each(|rival| *rival = grown(rival, size.kept));
        }
        let rival = match rivals.is_empty() {
            true => None,
            false => Some(self.rival_test(phases, rivals, refine, patterned, &mut kept, &mut refinement)?),
        };
        if refine && rival.is_none() {
            let moves = Moves::All { patterned };
            (kept.pose, _) = self.refine(&kept.map, phases, moves, "chosen", kept.pose, None, &mut refinement)?;
        }
        // The kept pose's own pilot map, if the photo moved it: the
        // refinement's maps were solved from the map of where it began.
        if kept.pose != kept.piloted {
            phases.expect_more(1);
            kept.map = self.pilot(&kept.pose, phases)?;
            kept.scored = None;
        }
        // The refinement searched the lean among the rest.
        let lean = match refine {
            true => None,
            false => {
                let camera = &self.photo.camera;
                let lean_search = (
                    self.settings.pose_search.lean_step_deg,
                    self.settings.pose_search.lean_reach_deg,
                );
                let leaned = |pose: &Pose, deg: f32| hypotheses::leaned(pose, mesh, camera, deg);
                let pixels = match self.settings.pose_search.lean_on_checkerboard {
                    true => Pixels::Checkerboard,
                    false => Pixels::All,
                };
                self.search(phases, &mut kept, "lighting_lean", lean_search, pixels, &leaned)?
            }
        };
        Ok(Judged {
            pose: kept.pose,
            pilot: Some(kept.map),
            rival,
            size,
            lean,
            refinement,
        })
    }

    /// The pilot map at `pose`: solved from BRDF samples, coarse to fine,
    /// with the output's weighting; it guides and starts the later solves.
    fn pilot(&self, pose: &Pose, phases: &mut PhaseLog) -> Result<Vec<f64>> {
        let t1 = Instant::now();
        let lighting = &self.settings.lighting;
        let spp = lighting.final_spp(lighting.spp_pilot, self.photo.mask.count(), 1);
        let sampling = lighting.model.sampling(None);
        let fit = self.output_fit(pose, (spp, 78), sampling, Pixels::All, None, lighting.solve_iters)?;
        phases.push(PhaseReport {
            pose: Some(PoseRecord::from(pose)),
            ..lighting_report("lighting_pilot", &fit, t1)
        });
        Ok(fit.into_map())
    }

    /// A fit at `pose` on the searches' map size with the output's weighting
    /// and the searches' smoothness: `spp` samples per pixel seeded
    /// `seed_offset` past the settings' seed.
    fn output_fit(
        &self,
        pose: &Pose,
        (spp, seed_offset): (u32, u64),
        sampling: LightSampling,
        pixels: Pixels,
        start: Option<&[f64]>,
        max_iters: usize,
    ) -> Result<LightingFit> {
        let lighting = &self.settings.lighting;
        let terms = LightingTerms::quadratic(lighting.smoothness, lighting.method)?;
        let request = FitRequest {
            size: self.work,
            render: RenderSettings {
                spp,
                seed: self.settings.seed.wrapping_add(seed_offset),
            },
            sampling,
            terms: &terms,
            purpose: LightingPurpose::Output,
            pixels,
            start,
            max_iters,
            term_values: false,
        };
        fit_lighting(self.probe, self.photo, self.clipped, pose, &request, lighting)
    }

    /// A line search over one parameter of the kept pose (`candidate(pose,
    /// x)`), from its map and, over all pixels, its score if known; moves
    /// `kept` to the pose the search keeps. None when the pose was not
    /// searched or the search is off (`step` 0).
    fn search(
        &self,
        phases: &mut PhaseLog,
        kept: &mut Kept,
        phase: &str,
        (step, reach): (f32, f32),
        pixels: Pixels,
        candidate: &dyn Fn(&Pose, f32) -> Pose,
    ) -> Result<Option<LineSearchReport>> {
        if !self.searched || step <= 0.0 {
            return Ok(None);
        }
        let from = kept.pose;
        // The rival test's score of this pose serves a search over all
        // pixels that starts at it.
        let known = match pixels {
            Pixels::All => kept.scored.take(),
            _ => None,
        };
        let (pose, (_, map), report) =
            self.line_search(&kept.map, phases, phase, (step, reach), pixels, known, |x| {
                candidate(&from, x)
            })?;
        if report.kept != 0.0 {
            kept.scored = None;
        }
        (kept.pose, kept.map) = (pose, map);
        Ok(Some(report))
    }

    /// The chosen pose against its `rivals` (a symmetric probe's other end,
    /// where the outline hardly tells them apart; a patterned probe's
    /// close-ranked best other end and best half turn): each one's pilot
    /// map, and the searches' score at each (each refined first when
    /// `refine`); the best rival is kept if it beats the chosen pose by
    /// `Settings::search_margin_db`.
    fn rival_test(
        &self,
        phases: &mut PhaseLog,
        rivals: Vec<Pose>,
        refine: bool,
        patterned: bool,
        kept: &mut Kept,
        refinement: &mut Vec<RefinementStep>,
    ) -> Result<RivalReport> {
        phases.expect_more(1 + 2 * rivals.len());
        let score = |pose: &Pose, map: &[f64], phases: &mut PhaseLog| -> Result<(f64, Vec<f64>)> {
            let t1 = Instant::now();
            let (fit, score) = self.score(pose, map, Pixels::All)?;
            phases.push(PhaseReport {
                pose: Some(PoseRecord::from(pose)),
                ..lighting_report("lighting_rival", &fit, t1)
            });
            Ok((score, fit.into_map()))
        };
        // A small probe's pose is refined by the photo in full; a patterned
        // probe's turn, which the colour ranking leaves a few degrees off
        // (a grooved cap's grooves out of phase score lower than its wrong
        // end), before the ends and turns are compared.
        let moves = match (refine, patterned) {
            (true, _) => Some(Moves::All { patterned }),
            (false, true) => Some(Moves::Turn),
            (false, false) => None,
        };
        let mut chosen = score(&kept.pose, &kept.map, phases)?;
        if let Some(moves) = moves {
            let scored = Some(chosen);
            (kept.pose, chosen) = self.refine(&kept.map, phases, moves, "chosen", kept.pose, scored, refinement)?;
        }
        // Each rival's pilot map and score (refined as the chosen pose
        // was); the best-scored one is the test's. A rival the photo
        // cannot show (out of the view, no data pixel) is no rival.
        let db = |scored: &ScoredRival| scored.as_ref().map_or(f64::NEG_INFINITY, |((db, _), _)| *db);
        // A rival that differs from the chosen pose by a turn mapping the
        // probe on to itself renders the same photo: no choice to judge.
        let self_map = SelfMap::new(self.probe.asset, &self.settings.symmetry);
        let alike = |rival: &Pose| self_map.alike(kept.pose.rotation.inverse() * rival.rotation);
        let mut strongest = None;
        let mut distinct_db: Option<f64> = None;
        for rival_piloted in rivals {
            let rival_alike = alike(&rival_piloted);
            let mut rival = rival_piloted;
            let rival_scored = self.pilot(&rival, phases).and_then(|rival_map| {
                let mut scored = score(&rival, &rival_map, phases)?;
                if let Some(moves) = moves {
                    let known = Some(scored);
                    (rival, scored) = self.refine(&rival_map, phases, moves, "rival", rival, known, refinement)?;
                }
                Ok((scored, rival_map))
            });
            if !rival_alike {
                distinct_db = Some(distinct_db.unwrap_or(f64::NEG_INFINITY).max(db(&rival_scored)));
            }
            if strongest
                .as_ref()
                .is_none_or(|(_, _, best, _)| db(&rival_scored) > db(best))
            {
                strongest = Some((rival, rival_piloted, rival_scored, rival_alike));
            }
        }
        let (rival, rival_piloted, rival_scored, alike) = strongest.expect("at least one rival");
        let rival_db = db(&rival_scored);
        let report = RivalReport {
            rival_axis: (rival.rotation * Vec3::Y).to_array(),
            chosen_db: chosen.0,
            rival_db,
            kept_rival: rival_db > chosen.0 + self.settings.pose_search.search_margin_db,
            alike,
            distinct_db,
        };
        kept.scored = Some(match rival_scored {
            Ok((rival_score, rival_map)) if report.kept_rival => {
                (kept.pose, kept.map, kept.piloted) = (rival, rival_map, rival_piloted);
                rival_score
            }
            _ => chosen,
        });
        Ok(report)
    }

    /// The pose searches' measure of `pose`: the lighting solved there from
    /// the map `start` (of a pose near it) with MIS guided by that map
    /// ([`Settings::spp_lean`], `LightingSettings::lean_solve_iters`, on the pixels `pixels`
    /// keeps), and its data term's weighted error in -dB (higher is better;
    /// minus infinity with no data pixel left): the weighted error, not the
    /// PSNR, which a sun's highlight dominates.
    pub(in crate::estimate) fn score(&self, pose: &Pose, start: &[f64], pixels: Pixels) -> Result<(LightingFit, f64)> {
        let (lighting, work) = (&self.settings.lighting, self.work);
        let sampler = EnvSampler::new(&env_from_texels(start, work.0, work.1)?);
        let sampling = lighting.model.sampling(Some(&sampler));
        let spp = lighting.final_spp(lighting.spp_lean, self.photo.mask.count(), sampling.strategies());
        let fit = self.output_fit(
            pose,
            (spp, 79),
            sampling,
            pixels,
            Some(start),
            lighting.lean_solve_iters,
        )?;
        let score = match fit.weighted_sq_error() {
            error if error > 0.0 => -10.0 * error.log10(),
            _ => f64::NEG_INFINITY,
        };
        Ok((fit, score))
    }

    /// A line search over one parameter of the pose ([`line_search_max`] in
    /// steps of `step`, up to `reach` either way; `candidate(x)` is the pose
    /// at `x`, 0 the searched one), each candidate scored by
    /// [`PhotoJudge::score`] from the map `start` (`scored`: the searched
    /// pose's score and map, when they are known already). A candidate is
    /// kept only if it beats the searched pose by
    /// [`Settings::search_margin_db`]. Each candidate scored is a phase
    /// named `phase`. Returns the kept pose, its score and map, and the
    /// search's account.
    #[allow(clippy::too_many_arguments)]
    fn line_search(
        &self,
        start: &[f64],
        phases: &mut PhaseLog,
        phase: &str,
        (step, reach): (f32, f32),
        pixels: Pixels,
        mut scored: Option<(f64, Vec<f64>)>,
        candidate: impl Fn(f32) -> Pose,
    ) -> Result<(Pose, (f64, Vec<f64>), LineSearchReport)> {
        // The searched pose's map, and the best candidate's (not their transports).
        let mut centre: Option<Vec<f64>> = None;
        let mut best: Option<(f32, Vec<f64>, f64)> = None;
        let tried = line_search_max(step, reach, |x| {
            let t1 = Instant::now();
            let pose = candidate(x);
            let known = match x == 0.0 {
                true => scored.take(),
                false => None,
            };
            let (score, map) = match known {
                Some(known) => known,
                None => match self.score(&pose, start, pixels) {
                    Ok((fit, score)) => {
                        phases.expect_more(1);
                        phases.push(PhaseReport {
                            pose: Some(PoseRecord::from(&pose)),
                            ..lighting_report(phase, &fit, t1)
                        });
                        (score, fit.into_map())
                    }
                    // A pose that takes the probe out of the view is no candidate.
                    Err(_) if x != 0.0 => return Ok(f64::NEG_INFINITY),
                    Err(e) => return Err(e),
                },
            };
            if centre.is_none() {
                centre = Some(map.clone());
            }
            if best.as_ref().is_none_or(|b| score > b.2) {
                best = Some((x, map, score));
            }
            Ok(score)
        })?;
        let (x, map, score) = best.expect("the line search scores the searched pose");
        let (kept, kept_scored) = match score > tried[0].1 + self.settings.pose_search.search_margin_db {
            true => (x, (score, map)),
            false => (0.0, (tried[0].1, centre.expect("the searched pose is scored first"))),
        };
        Ok((candidate(kept), kept_scored, LineSearchReport { tried, kept }))
    }

    /// `pose` refined by the photo: line searches ([`PhotoJudge::line_search`],
    /// phase `lighting_refine`) over the lean, the sway
    /// ([`hypotheses::swayed`]) and, for a `patterned` probe, the turn about
    /// its axis, each from where the one before left it, in rounds until
    /// one keeps no move (at most `PoseSearchSettings::photo_refine_rounds`);
    /// or over the turn alone, once ([`Moves`]). Every
    /// candidate's lighting is solved from `start`, the map of a pose near
    /// it; `scored` is `pose`'s score, if known. Rounds, because the score
    /// ripples (its samples move with the pose) and a search whose first
    /// steps both score lower stops. Returns the pose, its score and map;
    /// each search goes to `steps`.
    #[allow(clippy::too_many_arguments)]
    pub(in crate::estimate) fn refine(
        &self,
        start: &[f64],
        phases: &mut PhaseLog,
        moves: Moves,
        candidate: &'static str,
        pose: Pose,
        scored: Option<(f64, Vec<f64>)>,
        steps: &mut Vec<RefinementStep>,
    ) -> Result<(Pose, (f64, Vec<f64>))> {
        let settings = self.settings;
        let (mut pose, mut scored) = (pose, scored);
        let lean = (settings.pose_search.lean_step_deg, settings.pose_search.lean_reach_deg);
        let turn_per_lean = settings.pose_search.turn_per_lean;
        let turn = (turn_per_lean * lean.0, turn_per_lean * lean.1);
        type Move = fn(&Pose, &Mesh, &Camera, f32) -> Pose;
        let directions: [(&'static str, (f32, f32), Move); 3] = [
            ("lean", lean, hypotheses::leaned),
            ("sway", lean, hypotheses::swayed),
            ("turn", turn, |pose, mesh, _, deg| hypotheses::turned(pose, mesh, deg)),
        ];
        let (mesh, camera) = (&self.probe.asset.mesh, &self.photo.camera);
        let (searched, rounds) = match moves {
            Moves::All { patterned } => (
                &directions[..2 + patterned as usize],
                settings.pose_search.photo_refine_rounds,
            ),
            Moves::Turn => (&directions[2..], 1),
        };
        for _ in 0..rounds {
            let mut moved = false;
            for &(direction, reach, moved_by) in searched {
                let from = pose;
                let (kept, kept_scored, search) = self.line_search(
                    start,
                    phases,
                    "lighting_refine",
                    reach,
                    Pixels::All,
                    scored.take(),
                    |x| moved_by(&from, mesh, camera, x),
                )?;
                moved |= search.kept != 0.0;
                (pose, scored) = (kept, Some(kept_scored));
                steps.push(RefinementStep {
                    candidate,
                    direction,
                    search,
                });
            }
            if !moved {
                break;
            }
        }
        Ok((pose, scored.expect("the searches score the pose")))
    }
}

/// Whether the photo refines the pose search's choice and rivals
/// (`Settings::photo_refine_px`; a lean search to refine by).
pub(in crate::estimate) fn photo_refines(photo: &Photo, settings: &Settings) -> bool {
    settings.pose_search.lean_step_deg > 0.0 && photo.mask.count() <= settings.pose_search.photo_refine_px
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimate::Quality;
    use crate::estimate::testing::{can_in_the_courtyard, probe_of};
    use glam::Vec3;

    #[test]
    fn the_photo_refines_a_small_can_s_axis_searching_its_lean_sway_and_turn_in_turn() {
        // A can of 1,713 px in a 160x120 photo: its label and the light
        // tell its pose, its outline hardly.
        let (asset, truth, photo) = can_in_the_courtyard(160, 120, Vec3::new(0.0, 0.15, 0.35));
        let probe = probe_of(&asset);
        let settings = Settings::new(Quality::Default);
        assert!(photo_refines(&photo, &settings), "{} px", photo.mask.count());
        // Off as the outline leaves a small probe: leaned 1.5 deg, swayed
        // 0.5, turned 3.
        let (mesh, camera) = (&asset.mesh, &photo.camera);
        let start = hypotheses::turned(
            &hypotheses::swayed(&hypotheses::leaned(&truth, mesh, camera, 1.5), mesh, camera, 0.5),
            mesh,
            3.0,
        );
        let clipped = vec![false; photo.camera.pixel_count()];
        let work = (128, 64);
        let pilot = fit_lighting(
            &probe,
            &photo,
            &clipped,
            &start,
            &FitRequest {
                size: work,
                render: RenderSettings { spp: 16, seed: 78 },
                sampling: settings.lighting.model.sampling(None),
                terms: &LightingTerms::quadratic(settings.lighting.smoothness, settings.lighting.method)
                    .expect("valid terms"),
                purpose: LightingPurpose::Output,
                pixels: Pixels::All,
                start: None,
                max_iters: settings.lighting.solve_iters,
                term_values: false,
            },
            &settings.lighting,
        )
        .expect("a pilot map")
        .into_map();
        let mut on_phase = |_: &PhaseReport, _: usize, _: usize| {};
        let mut phases = PhaseLog {
            phases: Vec::new(),
            expected: 0,
            on_phase: &mut on_phase,
        };
        let judge = PhotoJudge {
            probe: &probe,
            photo: &photo,
            clipped: &clipped,
            work,
            settings: &settings,
            searched: true,
        };
        let mut steps = Vec::new();
        let (refined, (score, _)) = judge
            .refine(
                &pilot,
                &mut phases,
                Moves::All { patterned: true },
                "chosen",
                start,
                None,
                &mut steps,
            )
            .expect("a refinement");
        // The axis: 1.58 -> 0.26 deg. (The turn, 3 deg off, gains 0.17 dB
        // at most here, under the searches' margin: this photo hardly
        // shows it.)
        let off = |p: &Pose| {
            (p.rotation * Vec3::Y)
                .angle_between(truth.rotation * Vec3::Y)
                .to_degrees()
        };
        assert!(
            off(&refined) < 0.3 * off(&start),
            "axis {} -> {} deg off",
            off(&start),
            off(&refined)
        );
        // Rounds of the three directions in order, each search's first
        // candidate where the one before left the pose.
        assert!(
            steps.len() >= 6 && steps.len().is_multiple_of(3),
            "{} searches",
            steps.len()
        );
        for (k, step) in steps.iter().enumerate() {
            assert_eq!(step.candidate, "chosen");
            assert_eq!(step.direction, ["lean", "sway", "turn"][k % 3]);
            assert_eq!(step.search.tried[0].0, 0.0);
        }
        let last = &steps[steps.len() - 1].search;
        assert_eq!(score, last.tried.iter().find(|t| t.0 == last.kept).expect("kept").1);
        // A probe without a pattern is not turned.
        let mut steps = Vec::new();
        judge
            .refine(
                &pilot,
                &mut phases,
                Moves::All { patterned: false },
                "rival",
                start,
                None,
                &mut steps,
            )
            .expect("a refinement");
        assert!(steps.iter().all(|s| s.direction != "turn" && s.candidate == "rival"));
        // The turn alone: one search, the axis where it was.
        let mut steps = Vec::new();
        let (turned, _) = judge
            .refine(&pilot, &mut phases, Moves::Turn, "rival", start, None, &mut steps)
            .expect("a refinement");
        assert_eq!(steps.len(), 1);
        assert_eq!(steps[0].direction, "turn");
        assert!((off(&turned) - off(&start)).abs() < 1e-3, "the axis moved");
    }

    /// The leans `line_search_max` tries on `score` (step 0.3, reach 2.4).
    fn leans_tried(score: impl Fn(f32) -> f64) -> Vec<(f32, f64)> {
        line_search_max(0.3, 2.4, |x| Ok(score(x))).unwrap()
    }

    /// The best lean tried.
    fn best(tried: &[(f32, f64)]) -> f32 {
        tried.iter().fold(tried[0], |b, &t| if t.1 > b.1 { t } else { b }).0
    }

    #[test]
    fn the_lean_search_finds_a_peak_near_the_start_or_walks_to_one_further_off_but_not_beyond_its_reach() {
        // A peak within a step: 0 and a step either way, then the vertex.
        let tried = leans_tried(|x| -(x as f64 - 0.1).powi(2));
        assert_eq!(tried.len(), 4);
        assert!((best(&tried) - 0.1).abs() < 1e-5, "{tried:?}");
        // A peak 1 deg off: steps doubling towards it until the score falls
        // (-0.6, -1.2, -2.4), then the vertex.
        let tried = leans_tried(|x| -(x as f64 + 1.0).powi(2));
        let leans: Vec<f32> = tried.iter().map(|t| t.0).collect();
        assert_eq!(&leans[..6], &[0.0, -0.3, 0.3, -0.6, -1.2, -2.4]);
        assert!((best(&tried) + 1.0).abs() < 1e-5, "{tried:?}");
        // A peak beyond the reach: the search stops at the reach.
        let tried = leans_tried(|x| -(x as f64 - 5.0).powi(2));
        assert!(tried.iter().all(|t| t.0.abs() <= 2.4), "{tried:?}");
        assert_eq!(best(&tried), 2.4);
        // A flat score: nothing but the start and a step either way.
        assert_eq!(leans_tried(|_| 1.0).len(), 3);
        // Leans past 0.5 cannot be scored (the probe leaves the view): the
        // walk stops there and no parabola runs through them.
        let tried = leans_tried(|x| match x > 0.5 {
            true => f64::NEG_INFINITY,
            false => -(x as f64 - 1.0).powi(2),
        });
        assert!(tried.iter().all(|t| t.0.is_finite()), "{tried:?}");
        assert_eq!(best(&tried), 0.3);
    }
}
