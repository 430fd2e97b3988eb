//! `alp synth` writes a complete scene folder that `alp eval` reads, and both fail clearly on bad input.

mod common;

use std::path::Path;
use std::process::Output;

use common::{alp, workspace};

use render::envmap::EnvMap;
use render::image_io::{Mask, RgbImage};

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn synth(env: &Path, out: &Path, extra: &[&str]) -> Output {
    synth_sized(env, out, ("96", "72"), extra)
}

/// `alp synth` of the can at `size` (width, height), 8 spp.
fn synth_sized(env: &Path, out: &Path, (width, height): (&str, &str), extra: &[&str]) -> Output {
    let mut args = vec!["synth", "--probe", "can", "--env"];
    args.push(env.to_str().expect("utf-8"));
    args.extend(["--out", out.to_str().expect("utf-8")]);
    args.extend(["--width", width, "--height", height, "--spp", "8"]);
    args.extend(extra);
    alp(&args)
}

/// `alp estimate` of the can in `scene` into `out`, with `extra` options.
fn estimate(scene: &Path, out: &Path, extra: &[&str]) -> Output {
    let s = |p: &Path| p.to_str().expect("utf-8").to_owned();
    let (image, mask, camera, out) = (
        s(&scene.join("image.exr")),
        s(&scene.join("mask.png")),
        s(&scene.join("camera.json")),
        s(out),
    );
    let mut args = vec!["estimate", "--image", &image, "--mask", &mask, "--camera", &camera];
    args.extend(["--probe", "can", "--out", &out]);
    args.extend(extra);
    alp(&args)
}

#[test]
fn synth_writes_a_scene_that_eval_reads() {
    let (dir, env) = workspace("synth-eval", 32);
    let scene = dir.join("scene");
    let out = synth(&env, &scene, &["--seed", "3", "--tilted", "--noise", "0.02"]);
    assert!(out.status.success(), "{}", stderr(&out));
    for file in [
        "image.exr",
        "mask.png",
        "camera.json",
        "probe.txt",
        "gt_env.exr",
        "pose.json",
    ] {
        assert!(scene.join(file).is_file(), "missing {file}");
    }
    assert_eq!(
        std::fs::read_to_string(scene.join("probe.txt"))
            .expect("probe.txt")
            .trim(),
        "can"
    );

    // The mask is the coverage: every mask pixel is lit, and lit pixels outside it are edge pixels.
    let image = RgbImage::read_exr(scene.join("image.exr")).expect("image");
    let mask = Mask::read_png(scene.join("mask.png")).expect("mask");
    assert_eq!((image.width, image.height, mask.width, mask.height), (96, 72, 96, 72));
    let (w, h) = (96i64, 72i64);
    let lit = |p: usize| image.pixels[p].iter().any(|&v| v > 0.0);
    let inside = |r: i64, c: i64| r >= 0 && c >= 0 && r < h && c < w && mask.inside[(r * w + c) as usize];
    let count = mask.count();
    assert!(count > 50, "the probe covers {count} pixels");
    for p in 0..(w * h) as usize {
        let (r, c) = (p as i64 / w, p as i64 % w);
        if mask.inside[p] {
            assert!(lit(p), "mask pixel ({r}, {c}) is black");
        } else if lit(p) {
            let near = (-1..=1).any(|dr| (-1..=1).any(|dc| inside(r + dr, c + dc)));
            assert!(near, "lit pixel ({r}, {c}) is away from the mask");
        }
    }
    // Reproducible from the seed.
    let again = dir.join("again");
    assert!(
        synth(&env, &again, &["--seed", "3", "--tilted", "--noise", "0.02"])
            .status
            .success()
    );
    for file in ["camera.json", "pose.json", "image.exr"] {
        let read = |d: &Path| std::fs::read(d.join(file)).expect("read");
        assert_eq!(read(&scene), read(&again), "{file} differs between runs of one seed");
    }

    // The truth against itself: no error.
    let scene_arg = scene.to_str().expect("utf-8");
    let gt = scene.join("gt_env.exr");
    let pose = scene.join("pose.json");
    let out = alp(&[
        "eval",
        "--scene",
        scene_arg,
        "--env",
        gt.to_str().expect("utf-8"),
        "--pose",
        pose.to_str().expect("utf-8"),
        "--spp",
        "16",
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let line = String::from_utf8(out.stdout).expect("utf-8");
    assert_eq!(line.lines().count(), 1, "{line}");
    let report: serde_json::Value = serde_json::from_str(&line).expect("JSON");
    assert_eq!(report["scene"], scene_arg);
    for sphere in ["mirror", "shiny", "diffuse"] {
        assert_eq!(report[sphere]["angular_deg"], 0.0, "{line}");
        assert_eq!(report[sphere]["si_rmse"], 0.0, "{line}");
    }
    for field in ["rotation_deg", "axis_deg", "translation_mm"] {
        assert!(report[field].as_f64().expect(field).abs() < 1e-3, "{line}");
    }
    assert!((report["scale_ratio"].as_f64().expect("scale_ratio") - 1.0).abs() < 1e-6);

    // A blurrier estimate scores worse than zero; without --pose there are no pose fields.
    let blurry = dir.join("blurry.exr");
    EnvMap::read(&gt)
        .expect("gt")
        .downsample(4)
        .write(&blurry)
        .expect("write");
    let out = alp(&[
        "eval",
        "--scene",
        scene_arg,
        "--env",
        blurry.to_str().expect("utf-8"),
        "--spp",
        "16",
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
    assert!(
        report["mirror"]["angular_deg"].as_f64().expect("mirror") > 1.0,
        "{report}"
    );
    assert!(report.get("rotation_deg").is_none(), "{report}");

    // A scene without its truth is an error naming the missing file.
    std::fs::remove_file(&gt).expect("remove gt_env.exr");
    let out = alp(&[
        "eval",
        "--scene",
        scene_arg,
        "--env",
        blurry.to_str().expect("utf-8"),
        "--spp",
        "16",
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("gt_env.exr"), "{}", stderr(&out));
    std::fs::remove_dir_all(&dir).expect("clean up");
}

#[test]
fn synth_rejects_an_unknown_probe_and_writes_nothing() {
    let (dir, env) = workspace("synth-bad-probe", 32);
    let scene = dir.join("scene");
    let out = alp(&[
        "synth",
        "--probe",
        "no_such_probe",
        "--env",
        env.to_str().expect("utf-8"),
        "--out",
        scene.to_str().expect("utf-8"),
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("no_such_probe"), "{}", stderr(&out));
    assert!(!scene.exists());
    // A bad env map is named too.
    let out = synth(&dir.join("missing.exr"), &scene, &[]);
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("missing.exr"), "{}", stderr(&out));
    std::fs::remove_dir_all(&dir).expect("clean up");
}

#[test]
fn estimate_takes_an_objective_file_and_refuses_a_bad_one_naming_the_line() {
    let (dir, env) = workspace("estimate-objective", 32);
    let scene = dir.join("scene");
    assert!(synth(&env, &scene, &["--seed", "5"]).status.success());
    let estimate = |objective: &Path, out: &Path| {
        let objective = objective.to_str().expect("utf-8");
        // One joint round: a pose phase that sees the objective's terms.
        let options = [
            "--quality",
            "fast",
            "--env-size",
            "32x16",
            "--rounds",
            "1",
            "--objective",
            objective,
        ];
        estimate(&scene, out, &options)
    };
    // Mask terms only for the pose (its phases then never render), and
    // for the lighting the data term and the paper's smoothness, which the
    // lighting phase minimises on a tape.
    let good = dir.join("masks_only.json");
    std::fs::write(
        &good,
        "{\"terms\": [\n  {\"term\": \"mask_l1\"},\n  {\"term\": \"chamfer\", \"weight\": 0.5},\n  \
         {\"term\": \"data_least_squares\"},\n  {\"term\": \"light_smoothness\", \"sigma_deg\": 5, \"weight\": 0.01}\n]}\n",
    )
    .expect("write objective");
    let out = estimate(&good, &dir.join("good"));
    assert!(out.status.success(), "{}", stderr(&out));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("good/report.json")).expect("report")).expect("json");
    let pose_phase = report["phases"]
        .as_array()
        .expect("phases")
        .iter()
        .find(|p| p["name"] == "pose")
        .expect("a pose phase");
    let names: Vec<&str> = pose_phase["per_iteration"][0]
        .as_array()
        .expect("terms")
        .iter()
        .map(|t| t["name"].as_str().expect("name"))
        .collect();
    assert_eq!(names, ["mask_l1", "chamfer"]);
    assert_eq!(
        report["objective"]["lighting"],
        serde_json::json!(["data_least_squares", "light_smoothness"])
    );
    assert_eq!(report["objective"]["lighting_solve"], "tape");
    let last = report["phases"].as_array().expect("phases").last().expect("a phase");
    assert_eq!(last["name"], "lighting_final");
    let loss = last["loss"].as_object().expect("the lighting terms' values");
    assert!(
        loss.contains_key("data_least_squares") && loss.contains_key("light_smoothness"),
        "{loss:?}"
    );

    // Without a lighting term the map would be unconstrained: an error
    // naming the file, before the photo is read.
    let no_lighting = dir.join("no_lighting.json");
    std::fs::write(&no_lighting, "{\"terms\": [{\"term\": \"mask_l1\"}]}\n").expect("write objective");
    let out = estimate(&no_lighting, &dir.join("no_lighting"));
    assert!(!out.status.success());
    assert!(
        stderr(&out).contains("no_lighting.json") && stderr(&out).contains("no term for the lighting phase"),
        "{}",
        stderr(&out)
    );

    let bad = dir.join("bad.json");
    std::fs::write(
        &bad,
        "{\"terms\": [\n  {\"term\": \"mask_l1\"},\n  {\"term\": \"sharpness\"}\n]}\n",
    )
    .expect("write objective");
    let out = estimate(&bad, &dir.join("bad"));
    assert!(!out.status.success());
    let message = stderr(&out);
    assert!(message.contains("line 3") && message.contains("sharpness"), "{message}");
    assert!(!dir.join("bad").exists(), "nothing is written on a bad objective");
    std::fs::remove_dir_all(&dir).expect("clean up");
}

#[test]
fn estimate_memory_stays_flat_from_one_phase_to_the_next() {
    let (dir, env) = workspace("estimate-memory", 32);
    let scene = dir.join("scene");
    let out = synth_sized(&env, &scene, ("160", "120"), &["--seed", "7"]);
    assert!(out.status.success(), "{}", stderr(&out));
    // Two joint rounds: pose and lighting phases to compare.
    let options = ["--env-size", "64x32", "--rounds", "2"];
    let out = estimate(&scene, &dir.join("estimate"), &options);
    assert!(out.status.success(), "{}", stderr(&out));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("estimate/report.json")).expect("report"))
            .expect("json");
    let phases = report["phases"].as_array().expect("phases");
    let resident = |name: &str| -> Vec<f64> {
        phases
            .iter()
            .filter(|p| p["name"] == name)
            .map(|p| p["resident_mb"].as_f64().expect("resident memory (Linux)"))
            .collect()
    };
    // Every phase of a kind does the same work on fresh tapes: the process
    // must not grow from one to the next (beyond the allocator's slack).
    for name in ["silhouette", "lighting_ranking", "pose", "lighting"] {
        let r = resident(name);
        assert!(r.len() >= 2, "{name}: {} phases", r.len());
        let first = r[..r.len() / 2].iter().cloned().fold(0.0, f64::max);
        let last = r[r.len() - 1];
        assert!(last <= 1.1 * first + 8.0, "{name}: resident {r:?} MB");
    }
    std::fs::remove_dir_all(&dir).expect("clean up");
}

/// `alp synth inputs` writes the inputs people have beside a scene, from its
/// seed, all of them or none; the estimate reads the JPEG it wrote as 8-bit,
/// finds its white clipped, and the blurred photo's blur.
#[test]
fn synth_inputs_writes_the_inputs_people_have_and_the_estimate_reads_them() {
    let (dir, env) = workspace("synth-inputs", 32);
    let scene = dir.join("scene");
    assert!(
        synth_sized(&env, &scene, ("160", "120"), &["--seed", "5"])
            .status
            .success()
    );
    let scene_arg = scene.to_str().expect("utf-8");
    let out = alp(&["synth", "inputs", "--scene", scene_arg, "--seed", "9"]);
    assert!(out.status.success(), "{}", stderr(&out));
    let files = [
        "mask_traced.png",
        "mask_segmenter.png",
        "image_blur.exr",
        "image.jpg",
        "box.txt",
        "inputs.json",
    ];
    let read = |f: &str| std::fs::read(scene.join(f)).expect(f);
    let first: Vec<Vec<u8>> = files.iter().map(|f| read(f)).collect();
    let exact = Mask::read_png(scene.join("mask.png")).expect("mask");
    for name in ["mask_traced.png", "mask_segmenter.png"] {
        let mask = Mask::read_png(scene.join(name)).expect(name);
        let changed = mask.inside.iter().zip(&exact.inside).filter(|(a, b)| a != b).count();
        assert!(
            changed > 0 && changed < exact.count() / 2,
            "{name}: {changed} pixels changed"
        );
    }
    let drawn: serde_json::Value = serde_json::from_slice(&read("inputs.json")).expect("JSON");
    let b: Vec<u32> = String::from_utf8(read("box.txt"))
        .expect("utf-8")
        .trim()
        .split(',')
        .map(|v| v.parse().expect("a number"))
        .collect();
    assert_eq!(serde_json::json!(b), drawn["probe_box"]);
    // The same seed draws the same inputs.
    assert!(
        alp(&["synth", "inputs", "--scene", scene_arg, "--seed", "9"])
            .status
            .success()
    );
    for (f, before) in files.iter().zip(&first) {
        assert_eq!(&read(f), before, "{f} differs between runs of one seed");
    }
    // The estimate of the JPEG finds its clipped white; of the blurred photo, its blur.
    let s = |p: &Path| p.to_str().expect("utf-8").to_owned();
    let (mask, camera) = (s(&scene.join("mask.png")), s(&scene.join("camera.json")));
    let box_text = String::from_utf8(read("box.txt")).expect("utf-8").trim().to_owned();
    let estimate = |image: &str, region: [&str; 2], name: &str, extra: &[&str]| -> Output {
        let (image, out) = (s(&scene.join(image)), s(&dir.join(name)));
        let mut args = vec!["estimate", "--image", &image, region[0], region[1]];
        args.extend(["--probe", "can", "--out", &out, "--quality", "fast", "--threads", "1"]);
        args.extend(extra);
        alp(&args)
    };
    let run = |image: &str, region: [&str; 2], name: &str| -> serde_json::Value {
        let run = estimate(image, region, name, &["--camera", &camera]);
        assert!(run.status.success(), "{}", stderr(&run));
        serde_json::from_slice(&std::fs::read(dir.join(name).join("report.json")).expect("report")).expect("JSON")
    };
    // A box in place of the mask: the outline found covers the probe's.
    run("image.exr", ["--box", &box_text], "from-box");
    let found = Mask::read_png(dir.join("from-box").join("mask_found.png")).expect("mask_found.png");
    let both = found
        .inside
        .iter()
        .zip(&exact.inside)
        .filter(|(a, b)| **a && **b)
        .count();
    let either = found
        .inside
        .iter()
        .zip(&exact.inside)
        .filter(|(a, b)| **a || **b)
        .count();
    assert!(
        both as f64 > 0.8 * either as f64,
        "the outline found overlaps the probe's by {both} of {either} pixels"
    );
    // A mask and a box at once, a bad box, and a photo without EXIF and no
    // --camera are errors that write nothing.
    for (region, extra, says, name) in [
        (
            ["--box", "1,2,3"],
            vec!["--camera", camera.as_str()],
            "--box",
            "bad-box",
        ),
        (
            ["--box", &box_text],
            vec!["--mask", mask.as_str(), "--camera", camera.as_str()],
            "--mask",
            "both",
        ),
        (["--mask", &mask], vec![], "--camera", "no-camera"),
    ] {
        let out = estimate("image.exr", region, name, &extra);
        assert!(!out.status.success(), "{name}");
        assert!(stderr(&out).contains(says), "{name}: {}", stderr(&out));
        assert!(!dir.join(name).exists(), "{name}: written");
    }
    let jpeg = run("image.jpg", ["--mask", &mask], "from-jpeg");
    assert!(
        jpeg["clipped_pixels"].as_u64().expect("clipped") > 0,
        "{}",
        jpeg["clipped_pixels"]
    );
    let blurred = run("image_blur.exr", ["--mask", &mask], "from-blur");
    let (found, drawn_blur) = (
        blurred["blur"]["blur_px"].as_f64().expect("blur"),
        drawn["blur_px"].as_f64().expect("drawn blur"),
    );
    assert!((found - drawn_blur).abs() < 0.5, "blur {found}, drawn {drawn_blur}");
    // A scene without its mask is an error naming the file, and writes nothing.
    std::fs::remove_file(scene.join("mask.png")).expect("remove");
    let bare = dir.join("bare");
    std::fs::create_dir_all(&bare).expect("dir");
    for f in ["image.exr", "camera.json"] {
        std::fs::copy(scene.join(f), bare.join(f)).expect("copy");
    }
    let out = alp(&["synth", "inputs", "--scene", bare.to_str().expect("utf-8")]);
    assert!(!out.status.success());
    assert!(stderr(&out).contains("mask.png"), "{}", stderr(&out));
    assert_eq!(std::fs::read_dir(&bare).expect("dir").count(), 2, "nothing written");
}
