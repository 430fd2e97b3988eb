//! `alp study speed-accuracy` on two tiny scenes: the files appear, the CSV
//! parses, the chart is SVG with the expected series, a resumed run skips
//! finished rows, and bad flags are clear errors.

mod common;

use std::path::Path;

use common::{alp, workspace};

/// Two 128x96 scenes of the can (16 spp) under the map at `env`, in `dir/scenes`.
fn scenes(dir: &Path, env: &Path) -> std::path::PathBuf {
    let scenes = dir.join("scenes");
    for seed in ["1", "2"] {
        let out = scenes.join(format!("can_{seed}"));
        let run = alp(&[
            "synth",
            "--probe",
            "can",
            "--env",
            env.to_str().expect("utf-8"),
            "--out",
            out.to_str().expect("utf-8"),
            "--seed",
            seed,
            "--spp",
            "16",
            "--width",
            "128",
            "--height",
            "96",
        ]);
        assert!(run.status.success(), "synth: {}", String::from_utf8_lossy(&run.stderr));
    }
    scenes
}

fn study(scenes: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    let mut args = vec![
        "study",
        "speed-accuracy",
        "--scenes",
        scenes.to_str().expect("utf-8"),
        "--out",
        out.to_str().expect("utf-8"),
    ];
    if !extra.contains(&"--eval-spp") {
        args.extend_from_slice(&["--eval-spp", "4"]);
    }
    args.extend_from_slice(extra);
    alp(&args)
}

#[test]
fn a_study_writes_its_tables_and_chart_and_a_rerun_skips_what_it_has() {
    let (dir, env) = workspace("study", 16);
    let scenes = scenes(&dir, &env);
    let out = dir.join("study");
    // The outside method with a Python that does not exist: skipped, with a note.
    let run = study(
        &scenes,
        &out,
        &[
            "--families",
            "threads,mitsuba",
            "--mitsuba-python",
            "/nonexistent/python3",
        ],
    );
    assert!(run.status.success(), "study: {}", String::from_utf8_lossy(&run.stderr));
    for file in [
        "results.jsonl",
        "results.csv",
        "summary.csv",
        "summary.md",
        "paired.md",
        "speed_accuracy.svg",
    ] {
        assert!(out.join(file).is_file(), "no {file}");
    }
    let csv = std::fs::read_to_string(out.join("results.csv")).expect("csv");
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().expect("a header").split(',').collect();
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), 4, "two scenes, default and threads=1: {csv}");
    let column = |name: &str| header.iter().position(|h| *h == name).expect(name);
    for row in &rows {
        assert_eq!(row.len(), header.len(), "{row:?}");
        let mirror: f64 = row[column("mirror_deg")].parse().expect("a mirror error");
        let wall: f64 = row[column("wall_s")].parse().expect("a wall time");
        assert!(mirror.is_finite() && mirror >= 0.0 && wall > 0.0, "{row:?}");
        assert!(["true", "false"].contains(&row[column("pose_found")]));
        assert_eq!(row[column("error")], "");
    }
    let variants: Vec<&str> = rows.iter().map(|r| r[column("variant")]).collect();
    assert_eq!(variants, ["default", "threads=1", "default", "threads=1"]);
    let summary = std::fs::read_to_string(out.join("summary.md")).expect("summary");
    assert!(summary.contains("| threads | threads=1 | 2 |"), "{summary}");
    // Outputs do not depend on the threads: no change on either scene.
    let paired = std::fs::read_to_string(out.join("paired.md")).expect("paired");
    assert!(
        paired.contains("against `default`")
            && paired.contains("| threads | threads=1 | 2 | +0.00 +- 0.00 / +0.00 +- 0.00 / +0.00 +- 0.00 |"),
        "{paired}"
    );
    assert!(
        summary.contains("outside method") && summary.contains("skipped"),
        "{summary}"
    );
    let svg = std::fs::read_to_string(out.join("speed_accuracy.svg")).expect("svg");
    assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
    for text in [
        "mirror sphere",
        "shiny sphere",
        "diffuse sphere",
        "threads",
        "Pareto front",
        "default",
    ] {
        assert!(svg.contains(text), "no `{text}` in the chart");
    }
    // A rerun with one family more runs only its settings.
    let before = std::fs::read_to_string(out.join("results.jsonl")).expect("jsonl");
    let run = study(&scenes, &out, &["--families", "threads,lighting"]);
    assert!(run.status.success(), "rerun: {}", String::from_utf8_lossy(&run.stderr));
    let after = std::fs::read_to_string(out.join("results.jsonl")).expect("jsonl");
    assert!(after.starts_with(&before), "the finished rows were redone");
    let added: Vec<&str> = after[before.len()..].lines().collect();
    assert_eq!(added.len(), 2, "{added:?}");
    assert!(added.iter().all(|l| l.contains("\"variant\":\"lighting=adam\"")));
    // --before: an earlier run's rows (here a copy of this one's) paired
    // setting by setting with this run's, its front drawn beside this one's.
    let earlier = dir.join("earlier");
    std::fs::create_dir_all(&earlier).expect("mkdir");
    std::fs::write(earlier.join("results.jsonl"), &after).expect("write");
    let tables_before = |earlier: &Path| {
        let flags = ["--families", "threads,lighting", "--tables-only", "--before"];
        let mut flags = flags.to_vec();
        flags.push(earlier.to_str().expect("utf-8"));
        study(&scenes, &out, &flags)
    };
    let run = tables_before(&earlier);
    assert!(run.status.success(), "before: {}", String::from_utf8_lossy(&run.stderr));
    let paired = std::fs::read_to_string(out.join("before.md")).expect("before.md");
    assert!(
        paired.contains("against the same setting in")
            && paired.contains("| threads | threads=1 | 2 | +0.00 +- 0.00 / +0.00 +- 0.00 / +0.00 +- 0.00 | 1.00 |")
            && paired.contains("| default | default | 2 |"),
        "{paired}"
    );
    assert!(out.join("before.csv").is_file());
    let svg = std::fs::read_to_string(out.join("speed_accuracy.svg")).expect("svg");
    assert!(svg.contains("Pareto front before") && svg.contains("default before"));
    // An earlier folder without a study, or with none of these scenes: clear errors.
    let e = tables_before(&dir.join("nothing"));
    let stderr = String::from_utf8_lossy(&e.stderr);
    assert!(
        !e.status.success() && stderr.contains("results.jsonl") && stderr.contains("missing"),
        "{stderr}"
    );
    std::fs::write(earlier.join("results.jsonl"), after.replace("\"can_", "\"tin_")).expect("write");
    let e = tables_before(&earlier);
    let stderr = String::from_utf8_lossy(&e.stderr);
    assert!(
        !e.status.success() && stderr.contains("--before") && stderr.contains("no run"),
        "{stderr}"
    );
    // A rerun on one of the scenes runs nothing and tables that scene only.
    let run = study(&scenes.join("can_1"), &out, &["--families", "threads,lighting"]);
    assert!(
        run.status.success(),
        "one scene: {}",
        String::from_utf8_lossy(&run.stderr)
    );
    let csv = std::fs::read_to_string(out.join("results.csv")).expect("results.csv");
    assert_eq!(csv.lines().count(), 1 + 3, "one scene's three settings: {csv}");

    // --tables-only runs nothing and leaves results.jsonl as it is, even a
    // last line still being written; a scene a setting has not run on yet
    // is left out of the tables, with a note.
    let rows: Vec<&str> = after.lines().collect();
    let (last, kept) = rows.split_last().expect("rows");
    let scene_of_last = ["can_1", "can_2"]
        .into_iter()
        .find(|s| last.contains(&format!("\"scene\":\"{s}\"")))
        .expect("a scene");
    let partial = kept.join("\n") + "\n" + &last[..20];
    std::fs::write(out.join("results.jsonl"), &partial).expect("write");
    std::fs::remove_file(out.join("summary.md")).expect("remove");
    let run = study(&scenes, &out, &["--families", "threads,lighting", "--tables-only"]);
    assert!(run.status.success(), "tables: {}", String::from_utf8_lossy(&run.stderr));
    assert_eq!(
        std::fs::read_to_string(out.join("results.jsonl")).expect("jsonl"),
        partial,
        "--tables-only changed results.jsonl"
    );
    let summary = std::fs::read_to_string(out.join("summary.md")).expect("summary");
    assert!(
        summary.contains("| lighting | lighting=adam | 1 |")
            && summary.contains("1 of the 2 scenes left out")
            && summary.contains(scene_of_last),
        "{summary}"
    );
    let e = study(&scenes, &dir.join("nothing"), &["--tables-only"]);
    let stderr = String::from_utf8_lossy(&e.stderr);
    assert!(!e.status.success() && stderr.contains("results.jsonl"), "{stderr}");
    std::fs::remove_dir_all(&dir).expect("clean up");
}

#[test]
fn bad_study_flags_and_folders_are_clear_errors() {
    let (dir, env) = workspace("study-bad", 8);
    let out = dir.join("out");
    let stderr = |run: std::process::Output| {
        assert!(!run.status.success());
        String::from_utf8_lossy(&run.stderr).into_owned()
    };
    let empty = dir.join("empty");
    std::fs::create_dir_all(&empty).expect("mkdir");
    let e = stderr(study(&empty, &out, &[]));
    assert!(e.contains("empty") && e.contains("no scene folder"), "{e}");
    let scenes = scenes(&dir, &env);
    let e = stderr(study(&scenes, &out, &["--families", "colour"]));
    assert!(e.contains("--families") && e.contains("colour"), "{e}");
    let e = stderr(study(&scenes, &out, &["--eval-spp", "5"]));
    assert!(e.contains("--eval-spp") && e.contains("square"), "{e}");
    // A scene whose probe.txt names nothing: the file is named, nothing is run.
    std::fs::write(scenes.join("can_2/probe.txt"), "\n").expect("write");
    let e = stderr(study(&scenes, &out, &["--families", "threads"]));
    assert!(e.contains("probe.txt") && e.contains("empty"), "{e}");
    assert!(
        !out.join("results.jsonl").exists(),
        "a run started before the scenes were checked"
    );
    std::fs::remove_dir_all(&dir).expect("clean up");
}

#[test]
fn the_stability_study_perturbs_grades_and_never_panics_or_goes_non_finite() {
    let (dir, env) = workspace("study-stability", 16);
    let scenes = scenes(&dir, &env);
    let out = dir.join("stability");
    let run = alp(&[
        "study",
        "stability",
        "--scenes",
        scenes.join("can_1").to_str().expect("utf-8"),
        "--out",
        out.to_str().expect("utf-8"),
        "--eval-spp",
        "4",
        "--perturbations",
        "small,noise,one_start",
    ]);
    assert!(run.status.success(), "study: {}", String::from_utf8_lossy(&run.stderr));
    for file in [
        "results.jsonl",
        "results.csv",
        "stability.csv",
        "stability.md",
        "paired.md",
        "stability.svg",
    ] {
        assert!(out.join(file).is_file(), "no {file}");
    }
    let rows: Vec<serde_json::Value> = std::fs::read_to_string(out.join("results.jsonl"))
        .expect("rows")
        .lines()
        .map(|l| serde_json::from_str(l).expect("a JSON row"))
        .collect();
    let variants: Vec<&str> = rows.iter().map(|r| r["variant"].as_str().expect("variant")).collect();
    assert_eq!(
        variants,
        [
            "unperturbed",
            "small=120",
            "small=80",
            "small=40",
            "noise=0.01",
            "noise=0.03",
            "noise=0.1",
            "one_start"
        ]
    );
    // The can is under 40 px tall in the 96 px photo: no strength of `small` makes it smaller.
    let skipped: Vec<bool> = rows.iter().map(|r| !r["skipped"].is_null()).collect();
    assert_eq!(
        skipped,
        [false, true, true, true, false, false, false, false],
        "{rows:?}"
    );
    for r in rows.iter().filter(|r| r["skipped"].is_null()) {
        assert_eq!(r["non_finite"], false, "{r}");
        assert!(r["error"].is_null(), "{r}");
        assert!(r["mirror_deg"].as_f64().is_some_and(f64::is_finite), "{r}");
    }
    assert_eq!(rows[6]["level"], 3);
    let table = std::fs::read_to_string(out.join("stability.md")).expect("table");
    assert!(table.contains("| small | small=40 | 0 | 0 / 0 |"), "{table}");
    assert!(
        table.contains("| noise | noise=0.1 | 1 |") && table.contains("| one_start | one_start | 1 |"),
        "{table}"
    );
    let paired = std::fs::read_to_string(out.join("paired.md")).expect("paired");
    assert!(
        paired.contains("against `unperturbed`") && paired.contains("| noise | noise=0.1 | 1 | "),
        "{paired}"
    );
    let svg = std::fs::read_to_string(out.join("stability.svg")).expect("svg");
    assert!(svg.starts_with("<svg") && svg.contains("one_start") && svg.contains("noise"));
    std::fs::remove_dir_all(&dir).expect("clean up");
}
