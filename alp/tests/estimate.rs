//! The main job end to end on a small synthetic photo: it must find the
//! probe where it is and explain the photo; bad inputs are clear errors.

use alp::estimate::{Photo, ProbeBsdf, Quality, Settings, estimate, estimate_with};
use glam::{Quat, Vec3};
use render::bsdf::{Bsdf, GgxMetal, Lambertian};
use render::camera::Camera;
use render::envmap::EnvMap;
use render::image_io::Mask;
use render::integrator::{RenderSettings, render_image};
use render::pose::Pose;
use render::probe::ProbeAsset;
use render::procedural::{SodaCan, ThermosCap, UvSphere};

/// A 160x120 photo (16 spp) of `probe` at `truth` from `eye`, looking at
/// `target`, under the bundled courtyard map.
fn photo_of(probe: &render::probe::ProbeAsset, truth: &Pose, eye: Vec3, target: Vec3) -> Photo {
    photo_sized(probe, truth, eye, target, (160, 120))
}

/// [`photo_of`] at `width x height`.
fn photo_sized(probe: &render::probe::ProbeAsset, truth: &Pose, eye: Vec3, target: Vec3, size: (u32, u32)) -> Photo {
    photo_in(probe, &GgxMetal, truth, eye, target, size)
}

/// [`photo_sized`] of a probe whose reflectance `bsdf` models.
fn photo_in(
    probe: &render::probe::ProbeAsset,
    bsdf: &dyn Bsdf<f32>,
    truth: &Pose,
    eye: Vec3,
    target: Vec3,
    (width, height): (u32, u32),
) -> Photo {
    let camera = Camera::new(width, height, 40.0, eye, target, Vec3::Y).expect("camera");
    let env_path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/envmaps/courtyard.exr");
    let env = EnvMap::read(env_path).expect("bundled env map").downsample(32);
    let (image, mask) = render_image(probe, truth, &camera, &env, bsdf, &RenderSettings { spp: 16, seed: 1 });
    Photo::new(image, mask, camera).expect("a valid photo")
}

/// A small photo of the can with its true pose, and fast settings with a
/// 64x32 output map.
fn scene() -> (render::probe::ProbeAsset, Pose, Photo, Settings) {
    let probe = SodaCan::default().build();
    let truth = Pose::new(Quat::from_rotation_y(0.3), 1.0, Vec3::new(0.01, 0.0, 0.0));
    let photo = photo_of(&probe, &truth, Vec3::new(0.0, 0.12, 0.3), Vec3::new(0.0, 0.06, 0.0));
    let mut settings = Settings::new(Quality::Fast);
    settings.env_size = (64, 32);
    (probe, truth, photo, settings)
}

#[test]
fn finds_the_probe_and_explains_the_photo() {
    let (probe, truth, photo, settings) = scene();
    let result = estimate(&photo, &probe, &settings).expect("an estimate");
    assert_eq!((result.env.width(), result.env.height()), (64, 32));
    assert_eq!(result.report.mask_on_border_pixels, 0, "the can is inside the photo");
    // Its label tells its ends and turns apart: no rival for the photo to judge.
    assert!(result.report.rival.is_none(), "{:?}", result.report.rival);
    let centre = Vec3::new(0.0, 0.061, 0.0);
    let err = (result.pose.transform_point(centre) - truth.transform_point(centre)).length();
    // Measured 0.0026 to 0.0095 m over photo seeds 1 to 4 (axis 1.2 to 4.2
    // deg; the turn about the axis 12 to 28 deg off: fast quality's four
    // starts are 90 deg apart, and a 160x120 photo shows little of the
    // label). With purely relative lighting weights: 0.0027 to 0.0057 m;
    // before the start stood upright in the world and took its depth from
    // the extent the turned mesh shows: 0.0095 to 0.0108 m.
    assert!(err < 0.012, "probe centre off by {err} m");
    let axis = (result.pose.rotation * Vec3::Y).dot(truth.rotation * Vec3::Y);
    assert!(axis > 0.99, "probe axis off by {} degrees", axis.acos().to_degrees());
    // Its size is known: the outline fits' drift in scale went into depth.
    assert_eq!(result.pose.scale, 1.0);
    assert!(
        result.report.psnr_db > 18.0,
        "re-render PSNR {} dB",
        result.report.psnr_db
    );
    assert!(
        result
            .env
            .radiance()
            .iter()
            .flatten()
            .all(|v| v.is_finite() && *v >= 0.0)
    );
}

#[test]
fn a_cap_of_one_colour_leaning_away_is_found_the_right_way_up() {
    // Seen from 7 deg above, a cap leaning 17 deg away from the camera
    // shows about the outline of one leaning as far towards it, and of
    // itself upside down. The silhouette fits from the upright and the
    // upside-down hypotheses stopped 3 and 7 deg from vertical; the best
    // outline was the upside-down one's depth mirror, the truth turned end
    // for end (chosen with depth mirrors alone: 179 deg off). Its end for
    // end twin is the truth, and fits a little better (0.0050 vs 0.0054).
    let probe = ThermosCap::default().build();
    let lean = Quat::from_rotation_x(-17f32.to_radians());
    let truth = Pose::new(lean * Quat::from_rotation_y(0.7), 1.0, Vec3::new(0.0, 0.0, 0.0));
    let photo = photo_of(&probe, &truth, Vec3::new(0.0, 0.05, 0.25), Vec3::new(0.0, 0.02, 0.0));
    let mut settings = Settings::new(Quality::Fast);
    settings.env_size = (64, 32);
    let result = estimate(&photo, &probe, &settings).expect("an estimate");
    let deg = axis_off(result.pose.rotation * Vec3::Y, &truth);
    assert!(deg < 5.0, "probe axis off by {deg} degrees");
}

/// The cap leaning 17 deg away as above, in a 320x240 photo whose mask
/// lost `pixels` outer rings of pixels (as `tools/eval_suite.py
/// --mask-error -1` shrinks it; gained them where `pixels` is negative):
/// the probe, its true pose and the photo.
fn cap_with_a_mask_too_narrow(pixels: i32) -> (ProbeAsset, Pose, Photo) {
    let probe = ThermosCap::default().build();
    let lean = Quat::from_rotation_x(-17f32.to_radians());
    let truth = Pose::new(lean * Quat::from_rotation_y(0.7), 1.0, Vec3::ZERO);
    let exact = photo_sized(
        &probe,
        &truth,
        Vec3::new(0.0, 0.05, 0.25),
        Vec3::new(0.0, 0.02, 0.0),
        (320, 240),
    );
    let (w, h) = (exact.mask.width as i64, exact.mask.height as i64);
    let mut narrow = exact.mask.inside.clone();
    for _ in 0..pixels.abs() {
        let inside = |x: i64, y: i64| x >= 0 && y >= 0 && x < w && y < h && narrow[(y * w + x) as usize];
        narrow = (0..w * h)
            .map(|p| {
                let (x, y) = (p % w, p / w);
                let mut cross = [(0, 0), (1, 0), (-1, 0), (0, 1), (0, -1)].iter();
                match pixels > 0 {
                    true => cross.all(|(dx, dy)| inside(x + dx, y + dy)),
                    false => cross.any(|(dx, dy)| inside(x + dx, y + dy)),
                }
            })
            .collect();
    }
    let narrow = Mask::new(w as usize, h as usize, narrow);
    let photo = Photo::new(exact.image.clone(), narrow, exact.camera).expect("a valid photo");
    (probe, truth, photo)
}

/// How far (degrees) `axis` is from the axis of `truth`.
fn axis_off(axis: Vec3, truth: &Pose) -> f32 {
    axis.dot(truth.rotation * Vec3::Y).clamp(-1.0, 1.0).acos().to_degrees()
}

#[test]
fn a_cap_whose_mask_is_a_pixel_too_narrow_has_its_ends_told_apart_by_the_photo() {
    // The outline hardly tells the cap's ends apart: the rival test lights
    // each end from its own pilot map, and the photo scores the right end
    // higher, whichever end the outline chose.
    // The lean search starts from the kept end's score (on every pixel,
    // as the rival test scores: a search on the checkerboard scores its
    // start again).
    let (result, truth, settings) = lean_searched_cap(false);
    let report = &result.report;
    let ends = report.rival.as_ref().expect("a symmetric probe's ends are tested");
    let chosen = &report.starts[report.chosen_start.expect("the pose was searched")];
    let outline = axis_off(Vec3::from_array(report.axes[chosen.axis].fitted_axis), &truth);
    let rival = axis_off(Vec3::from_array(ends.rival_axis), &truth);
    let (right_db, wrong_db) = match outline < rival {
        true => (ends.chosen_db, ends.rival_db),
        false => (ends.rival_db, ends.chosen_db),
    };
    assert!(
        outline.min(rival) < 10.0 && outline.max(rival) > 170.0,
        "the rival is the other end: {outline} and {rival} deg off"
    );
    assert!(right_db > wrong_db, "the photo prefers the wrong end: {ends:?}");
    assert_eq!(
        ends.kept_rival,
        ends.rival_db > ends.chosen_db + settings.pose_search.search_margin_db
    );
    let kept_db = if ends.kept_rival { ends.rival_db } else { ends.chosen_db };
    let lean = report.lean.as_ref().expect("a lean search");
    assert_eq!(lean.tried[0], (0.0, kept_db));
    assert_eq!(lean_phases(report), lean.tried.len() - 1, "the start's score is reused");
    let deg = axis_off(result.pose.rotation * Vec3::Y, &truth);
    assert!(deg < 5.0, "probe axis off by {deg} degrees");
}

/// The cap with a mask a pixel too narrow, estimated at fast quality with
/// a lean search (on a checkerboard of its pixels or on all): the
/// estimate, the true pose and the settings.
fn lean_searched_cap(on_checkerboard: bool) -> (alp::estimate::Estimate, Pose, Settings) {
    let (probe, truth, photo) = cap_with_a_mask_too_narrow(1);
    let mut settings = Settings::new(Quality::Fast);
    settings.env_size = (64, 32);
    settings.pose_search.lean_step_deg = 0.3;
    settings.pose_search.lean_on_checkerboard = on_checkerboard;
    let result = estimate(&photo, &probe, &settings).expect("an estimate");
    (result, truth, settings)
}

/// The lean search's scored candidates (one phase each).
fn lean_phases(report: &alp::estimate::Report) -> usize {
    report.phases.iter().filter(|p| p.name == "lighting_lean").count()
}

#[test]
fn the_lean_search_on_the_checkerboard_scores_its_start_on_its_own_pixels() {
    // The rival test scored the kept end on every pixel; a lean search on
    // half of them cannot compare against that score, and scores its
    // start again, as one more lean.
    assert!(
        Settings::default().pose_search.lean_on_checkerboard,
        "the default's lean search"
    );
    let (result, truth, _) = lean_searched_cap(true);
    let lean = result.report.lean.as_ref().expect("a lean search");
    assert_eq!(lean.tried[0].0, 0.0);
    assert_eq!(
        lean_phases(&result.report),
        lean.tried.len(),
        "every lean scored, the start too"
    );
    let deg = axis_off(result.pose.rotation * Vec3::Y, &truth);
    assert!(deg < 5.0, "probe axis off by {deg} degrees");
}

#[test]
fn the_size_search_goes_ahead_of_the_rival_test_and_the_rival_grows_with_the_chosen_pose() {
    // A mask two pixels too wide: the outline's pose is too large, and the
    // photo shrinks it (one pixel too narrow, it no longer tells).
    let (probe, truth, photo) = cap_with_a_mask_too_narrow(-2);
    let mut settings = Settings::new(Quality::Fast);
    settings.env_size = (64, 32);
    (settings.pose_search.size_step_px, settings.pose_search.lean_step_deg) = (0.5, 0.3);
    // Any gain keeps a size (the outline leaves it within 0.2 px).
    settings.pose_search.search_margin_db = 0.0;
    let result = estimate(&photo, &probe, &settings).expect("an estimate");
    let report = &result.report;
    let size = report.size.as_ref().expect("a size search");
    assert!(size.kept != 0.0, "no size kept, so no growth to test: {size:?}");
    let at = |name: &str| -> Vec<usize> {
        (0..report.phases.len())
            .filter(|&k| report.phases[k].name == name)
            .collect()
    };
    let (sizes, rivals) = (at("lighting_size"), at("lighting_rival"));
    assert!(!sizes.is_empty() && !rivals.is_empty(), "{sizes:?} {rivals:?}");
    assert!(
        sizes.iter().max() < rivals.iter().min(),
        "sizes {sizes:?}, rivals {rivals:?}"
    );
    // The rival test scores the chosen pose, then its rival, each at its
    // own probe size: the size the search kept, for both.
    let scale = |k: usize| report.phases[k].pose.as_ref().expect("a pose").scale;
    let chosen_scale = scale(rivals[0]);
    assert!(
        (scale(rivals[1]) - chosen_scale).abs() < 1e-4 * chosen_scale,
        "kept {} px: the chosen pose's scale {chosen_scale}, the rival's {}",
        size.kept,
        scale(rivals[1])
    );
    // The axis's line: which end is up this photo no longer tells at the
    // default search smoothness (the ends' scores 0.5 dB apart the wrong
    // way from a weight of 1e-3 up, the right way at 3e-4; train's cap 026
    // flipped alike: results 14.3). The sibling test with the mask one
    // pixel off still asks for the right end.
    let deg = axis_off(result.pose.rotation * Vec3::Y, &truth);
    assert!(deg.min(180.0 - deg) < 5.0, "probe axis off by {deg} degrees");
}

#[test]
fn the_final_solve_keeps_to_its_sample_budget() {
    // A probe of 8,000 px keeps the settings' samples; one filling a
    // 12-megapixel photo gets what the budget allows, and never less than
    // the least. With MIS each hit has two light samples.
    let lighting = Settings::default().lighting;
    let final_spp = |spp, pixels, strategies| lighting.final_spp(spp, pixels, strategies);
    assert_eq!(final_spp(128, 8_000, 1), 128);
    assert_eq!(final_spp(64, 8_000, 2), 64);
    assert!(final_spp(128, 51_000, 2) < 128);
    for strategies in [1, 2] {
        for pixels in [200_000, 1_000_000, 12_000_000] {
            let spp = final_spp(128, pixels, strategies);
            assert!(spp >= 16, "{pixels} pixels: {spp} spp");
            assert!(
                spp == 16 || spp as usize * pixels * strategies <= lighting.final_sample_budget,
                "{pixels} pixels: {spp} spp"
            );
        }
    }
    assert_eq!(final_spp(128, 50_000, 1), 41);
    assert_eq!(final_spp(128, 50_000, 2), 20);
}

#[test]
fn bad_photos_are_clear_errors() {
    let (
        _,
        _,
        Photo {
            image, mask, camera, ..
        },
        _,
    ) = scene();
    let empty = Mask::new(160, 120, vec![false; 160 * 120]);
    let err = Photo::new(image.clone(), empty, camera)
        .err()
        .expect("an empty mask is refused");
    assert!(err.to_string().contains("mask"), "{err}");
    let small = Mask::new(80, 60, vec![true; 80 * 60]);
    let err = Photo::new(image.clone(), small, camera)
        .err()
        .expect("a mask of another size is refused");
    assert!(err.to_string().contains("80x60"), "{err}");
    let mut nan = image;
    nan.pixels[5][1] = f32::NAN;
    let err = Photo::new(nan, mask, camera).err().expect("NaN is refused");
    assert!(err.to_string().contains("NaN"), "{err}");
}

#[test]
fn bad_settings_are_clear_errors() {
    let (probe, _, photo, settings) = scene();
    let refused = |settings: &Settings| {
        estimate(&photo, &probe, settings)
            .err()
            .expect("bad settings are refused")
            .to_string()
    };
    let err = refused(&Settings {
        env_size: (100, 30),
        ..settings.clone()
    });
    assert!(err.contains("100x30 is not a 2:1 map"), "{err}");
    for rows in [0, 182] {
        let mut bad = settings.clone();
        bad.lighting.working_height = Some(rows);
        let err = refused(&bad);
        assert!(
            err.contains(&format!("{rows} rows")) && err.contains("1 to 181"),
            "{err}"
        );
    }
}

#[test]
fn the_lighting_alone_at_the_true_pose_explains_the_photo() {
    let (probe, truth, photo, mut settings) = scene();
    settings.known_pose = Some(truth);
    let result = estimate(&photo, &probe, &settings).expect("an estimate");
    assert_eq!(result.pose, truth, "a known pose is kept");
    assert_eq!(
        result.report.final_spp, settings.lighting.spp_final,
        "a small probe takes every sample"
    );
    assert_eq!(result.report.chosen_start, None);
    assert!(result.report.lean.is_none(), "a known pose is not leaned");
    let psnr = result.report.psnr_db;
    assert!(psnr > 20.0, "re-render PSNR at the true pose: {psnr} dB");
}

#[test]
fn the_estimate_renders_the_probe_with_the_model_it_is_given() {
    // A can of the paper's metal and one of a diffuse (Lambertian) paint:
    // each photo is explained best by its own model, whatever map the
    // other solves for.
    let (probe, truth, metal_photo, mut settings) = scene();
    let diffuse_photo = photo_in(
        &probe,
        &Lambertian,
        &truth,
        Vec3::new(0.0, 0.12, 0.3),
        Vec3::new(0.0, 0.06, 0.0),
        (160, 120),
    );
    settings.known_pose = Some(truth);
    let psnr = |photo: &Photo, bsdf: &dyn ProbeBsdf, name: &str| {
        let result = estimate_with(photo, &probe, bsdf, &settings, &mut |_, _, _| {}).expect("an estimate");
        assert_eq!(result.report.bsdf, name, "the report names the model");
        result.report.psnr_db
    };
    let metal = [&metal_photo, &diffuse_photo].map(|photo| psnr(photo, &GgxMetal, "ggx_metal"));
    let diffuse = [&metal_photo, &diffuse_photo].map(|photo| psnr(photo, &Lambertian, "lambertian"));
    eprintln!("re-render PSNR (dB), metal / diffuse photo: metal model {metal:?}, diffuse model {diffuse:?}");
    assert!(metal[0] > diffuse[0] + 6.0, "the metal photo");
    assert!(diffuse[1] > metal[1] + 1.0, "the diffuse photo");
}

#[test]
fn the_estimate_is_the_same_at_any_exposure() {
    // A photo exposed 100 times longer or shorter holds the same scene: the
    // same pose, and the map times 100 or over it (its data and its priors
    // in the same balance), but for rounding: measured 0.1 and 0.2 % of the
    // map's level apart. With the data term over the weights' sum alone the
    // poses differed.
    let (probe, _, photo, mut settings) = scene();
    // A sharp camera: the blur measured on this small render (0.75 px)
    // spreads the pixels, leaves more of the map to the prior, and the
    // solves' rounding then moves it by 1-2 % (docs/results/benchmark.md 16).
    settings.photo.blur_px = Some(0.0);
    let exposed = |scale: f32| {
        let mut image = photo.image.clone();
        image.pixels.iter_mut().flatten().for_each(|v| *v *= scale);
        let scaled = Photo::new(image, photo.mask.clone(), photo.camera).expect("a photo");
        let found = estimate(&scaled, &probe, &settings).expect("an estimate");
        let map: Vec<f32> = found.env.radiance().iter().flatten().map(|v| v / scale).collect();
        (found.pose, map)
    };
    let (pose, map) = exposed(1.0);
    let level = map.iter().sum::<f32>() / map.len() as f32;
    for scale in [0.01, 100.0] {
        let (p, m) = exposed(scale);
        let turned = (p.rotation * pose.rotation.inverse()).to_axis_angle().1.to_degrees();
        let moved = (p.translation - pose.translation).length();
        assert!(
            turned < 0.05 && moved < 1e-4,
            "x{scale}: turned {turned} deg, moved {moved} m"
        );
        let off = m.iter().zip(&map).map(|(a, b)| (a - b).abs()).sum::<f32>() / m.len() as f32;
        assert!(
            off < 5e-3 * level,
            "x{scale}: the map off by {off} on a level of {level}"
        );
    }
}

#[test]
fn a_sharp_probe_s_map_is_solved_finer_than_its_pose_searches_maps() {
    let probe = UvSphere {
        radius: 0.03,
        roughness: 0.1,
        ..UvSphere::default()
    }
    .build();
    let truth = Pose::new(Quat::IDENTITY, 1.0, Vec3::new(0.0, 0.06, 0.0));
    let photo = photo_of(&probe, &truth, Vec3::new(0.0, 0.12, 0.3), Vec3::new(0.0, 0.06, 0.0));
    let mut settings = Settings::new(Quality::Default);
    settings.known_pose = Some(truth);
    settings.lighting.spp_final = 16;
    let result = estimate(&photo, &probe, &settings).expect("an estimate");
    // The final solve starts from the pilot map, solved at the searches' resolution.
    assert_eq!(result.report.working_resolution, (256, 128));
    assert_eq!(result.report.search_resolution, (128, 64));
    let psnr = result.report.psnr_db;
    assert!(psnr > 20.0, "re-render PSNR at the true pose: {psnr} dB");
}

#[test]
fn the_size_and_lean_searches_account_for_every_candidate_and_keep_the_best_only_by_their_margin() {
    let (probe, _, photo, mut settings) = scene();
    (settings.pose_search.size_step_px, settings.pose_search.lean_step_deg) = (0.5, 0.3);
    // A probe this small would have its pose refined by the photo instead
    // of the lean search alone (next test).
    settings.pose_search.photo_refine_px = 0;
    let result = estimate(&photo, &probe, &settings).expect("an estimate");
    let searches = [
        (
            "lighting_size",
            result.report.size.as_ref(),
            settings.pose_search.size_reach_px,
        ),
        (
            "lighting_lean",
            result.report.lean.as_ref(),
            settings.pose_search.lean_reach_deg,
        ),
    ];
    for (phase, search, reach) in searches {
        let search = search.unwrap_or_else(|| panic!("{phase}: a search"));
        let tried = &search.tried;
        assert_eq!(tried[0].0, 0.0, "{phase}: the searched pose is scored first");
        assert!(tried.len() >= 3, "{phase}: {tried:?}");
        assert!(tried.iter().all(|t| t.0.abs() <= reach), "{phase}: {tried:?}");
        let best = tried.iter().fold(tried[0], |b, &t| if t.1 > b.1 { t } else { b });
        match best.1 > tried[0].1 + settings.pose_search.search_margin_db {
            true => assert_eq!(search.kept, best.0, "{phase}: {tried:?}"),
            false => assert_eq!(search.kept, 0.0, "{phase}: {tried:?}"),
        }
        let phases: Vec<_> = result.report.phases.iter().filter(|p| p.name == phase).collect();
        let scored = tried.iter().filter(|t| t.1.is_finite()).count();
        assert_eq!(phases.len(), scored, "{phase}: one phase per candidate scored");
        assert!(
            phases
                .iter()
                .all(|p| p.pose.is_some() && p.loss.contains_key("data_weighted_sq_error"))
        );
    }
}

#[test]
fn a_small_probe_s_pose_is_refined_by_the_photo_in_place_of_the_lean_search() {
    let (probe, truth, photo, mut settings) = scene();
    settings.pose_search.lean_step_deg = 0.3;
    assert!(
        photo.mask.count() <= settings.pose_search.photo_refine_px,
        "{} px",
        photo.mask.count()
    );
    let result = estimate(&photo, &probe, &settings).expect("an estimate");
    let report = &result.report;
    assert!(report.lean.is_none(), "the refinement searched the lean");
    let steps = &report.photo_refinement;
    // The can's label shows: its turn is searched, and it has no rival.
    assert!(
        steps.len() >= 3 && steps.len().is_multiple_of(3),
        "{} searches",
        steps.len()
    );
    for (k, step) in steps.iter().enumerate() {
        assert_eq!(
            (step.candidate, step.direction),
            ("chosen", ["lean", "sway", "turn"][k % 3])
        );
    }
    // Every candidate scored is a phase, the searched poses' scores
    // carried from one search to the next.
    let scored: usize = steps
        .iter()
        .map(|s| s.search.tried.iter().skip(1).filter(|t| t.1.is_finite()).count())
        .sum();
    let phases = report.phases.iter().filter(|p| p.name == "lighting_refine").count();
    assert_eq!(phases, scored + 1, "the first search scores its start too");
    let off = (result.pose.rotation * Vec3::Y)
        .angle_between(truth.rotation * Vec3::Y)
        .to_degrees();
    // 0.18 deg, as with the lean search alone: this can's outline pins its
    // axis already (the refinement's gain is `refine_by_photo`'s test's).
    assert!(off < 0.5, "axis {off} deg off");
}

#[test]
fn a_photo_whose_mask_outgrows_the_budget_is_worked_on_box_filtered_and_re_rendered_at_its_size() {
    let (probe, truth, photo, mut settings) = scene();
    // A budget a third of the mask: the photo is worked on at about
    // 1 / sqrt(3) of its size.
    settings.photo.working_mask_pixels = photo.mask.count().div_ceil(3);
    let result = estimate(&photo, &probe, &settings).expect("an estimate");
    let working = &result.report.working_image;
    let factor = (photo.mask.count() as f64 / settings.photo.working_mask_pixels as f64).sqrt();
    assert!((working.factor - factor).abs() < 1e-12, "{working:?}");
    assert_eq!(working.size, ((160.0 / factor) as usize, (120.0 / factor) as usize));
    let budget = settings.photo.working_mask_pixels as f64;
    assert!(
        (working.mask_pixels as f64 - budget).abs() < 0.1 * budget,
        "{working:?}"
    );
    let centre = Vec3::new(0.0, 0.061, 0.0);
    let err = (result.pose.transform_point(centre) - truth.transform_point(centre)).length();
    assert!(err < 0.012, "probe centre off by {err} m");
    let axis = (result.pose.rotation * Vec3::Y).dot(truth.rotation * Vec3::Y);
    assert!(axis > 0.99, "probe axis off by {} degrees", axis.acos().to_degrees());
    // The re-render is the photo's size and explains the photo there.
    let rerender = &result.rerender;
    assert_eq!((rerender.width, rerender.height), (160, 120));
    let inside: Vec<usize> = (0..160 * 120).filter(|&i| photo.mask.inside[i]).collect();
    let peak = inside
        .iter()
        .flat_map(|&i| photo.image.pixels[i])
        .fold(0.0f32, f32::max) as f64;
    let mse = inside
        .iter()
        .flat_map(|&i| (0..3).map(move |c| (i, c)))
        .map(|(i, c)| (rerender.pixels[i][c] as f64 - photo.image.pixels[i][c] as f64).powi(2))
        .sum::<f64>()
        / (3 * inside.len()) as f64;
    let psnr = 10.0 * (peak * peak / mse).log10();
    // Measured 29.3 dB (the probe's centre 1.8 mm off, its axis 0.6 deg).
    assert!(psnr > 25.0, "full-size re-render PSNR {psnr} dB");
}

#[test]
fn a_probe_built_along_another_axis_is_found_as_one_built_along_y() {
    // The test scene's photo, of the can whose mesh lies along -X: the same
    // object, posed so as to make the same photo.
    let (probe, truth, photo, settings) = scene();
    let built = Quat::from_rotation_z(std::f32::consts::FRAC_PI_2);
    let along_x = render::probe::ProbeAsset {
        mesh: probe.mesh.posed(&Pose::new(built, 1.0, Vec3::ZERO)),
        ..probe.clone()
    };
    let truth = Pose::new(truth.rotation * built.inverse(), truth.scale, truth.translation);
    let result = estimate(&photo, &along_x, &settings).expect("an estimate");
    let axis = Vec3::from_array(result.report.probe_axis);
    assert!(axis.x.abs() > 0.999, "the probe's axis found along {axis}");
    let centre = built * Vec3::new(0.0, 0.061, 0.0);
    let err = (result.pose.transform_point(centre) - truth.transform_point(centre)).length();
    assert!(err < 0.012, "probe centre off by {err} m");
    let lid = built * Vec3::Y;
    let tilt = (result.pose.rotation * lid).dot(truth.rotation * lid);
    assert!(tilt > 0.99, "probe axis off by {} degrees", tilt.acos().to_degrees());
    // The lighting alone at the true pose, given in the mesh's own frame.
    let mut known = settings.clone();
    known.known_pose = Some(truth);
    let result = estimate(&photo, &along_x, &known).expect("an estimate");
    assert_eq!(result.pose, truth, "a known pose is kept");
    assert!(result.report.psnr_db > 20.0, "PSNR {} dB", result.report.psnr_db);
}
