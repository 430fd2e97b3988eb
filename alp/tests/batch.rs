//! `alp batch`: two shards and a merge give what one run gives; a killed
//! run resumes without redoing finished photos; a broken line is reported
//! and the rest go on.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn alp(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_alp"))
        .args(args)
        .output()
        .expect("run alp")
}

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

/// Lines of a summary file as (id, status).
fn statuses(path: &Path) -> Vec<(String, String)> {
    std::fs::read_to_string(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .lines()
        .map(|l| {
            let v: serde_json::Value = serde_json::from_str(l).expect("summary line");
            (
                v["id"].as_str().expect("id").to_string(),
                v["status"].as_str().expect("status").to_string(),
            )
        })
        .collect()
}

fn pair(id: &str, status: &str) -> (String, String) {
    (id.to_string(), status.to_string())
}

/// An empty folder of the system's temp dir, named `name` and this process.
fn fresh_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

/// A 96x72 scene of `probe` under the studio map, from `seed`, written to `scene`.
fn synth_scene(scene: &Path, probe: &str, seed: usize) {
    let env = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets/envmaps/studio.exr");
    let seed = seed.to_string();
    let made = alp(&[
        "synth",
        "--probe",
        probe,
        "--env",
        s(&env),
        "--out",
        s(scene),
        "--seed",
        &seed,
        "--width",
        "96",
        "--height",
        "72",
        "--spp",
        "16",
    ]);
    assert!(made.status.success(), "{}", String::from_utf8_lossy(&made.stderr));
}

#[test]
fn shards_resume_and_broken_lines() {
    let dir = fresh_dir("alp-batch");
    for (i, probe) in ["can", "cap", "can"].iter().enumerate() {
        synth_scene(&dir.join(format!("s{i}")), probe, i);
    }
    let line = |id: &str, scene: &str, probe: &str| {
        format!(
            r#"{{"id": "{id}", "image": "{scene}/image.exr", "mask": "{scene}/mask.png", "camera": "{scene}/camera.json", "probe": "{probe}", "quality": "fast"}}"#
        )
    };
    let manifest = dir.join("manifest.jsonl");
    let lines = [
        line("p0", "s0", "can"),
        "{\"id\": broken".to_string(),
        line("p1", "s1", "cap"),
        line("p2", "s2", "can"),
        line("p1", "s2", "can"),
        line("p3", "missing", "can"),
    ];
    std::fs::write(&manifest, lines.join("\n") + "\n").expect("manifest");

    // One run: the good lines done, the broken, duplicate and missing ones reported, a failing exit.
    let whole = dir.join("whole");
    let run = alp(&[
        "batch",
        "--manifest",
        s(&manifest),
        "--out",
        s(&whole),
        "--threads",
        "2",
    ]);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success(), "failures give a failing exit");
    assert!(
        stderr.contains("line 2") && stderr.contains("p1") && stderr.contains("missing"),
        "{stderr}"
    );
    let expected = vec![
        pair("p0", "done"),
        pair("line 2", "failed"),
        pair("p1", "done"),
        pair("p2", "done"),
        pair("p1", "failed"),
        pair("p3", "failed"),
    ];
    assert_eq!(statuses(&whole.join("summary-0-of-1.jsonl")), expected);

    // Two shards and a merge: the same table and the same estimates.
    let sharded = dir.join("sharded");
    for shard in ["0/2", "1/2"] {
        alp(&[
            "batch",
            "--manifest",
            s(&manifest),
            "--out",
            s(&sharded),
            "--shard",
            shard,
            "--threads",
            "1",
        ]);
    }
    assert_eq!(
        statuses(&sharded.join("summary-0-of-2.jsonl")),
        vec![pair("p0", "done"), pair("p1", "done"), pair("p1", "failed")]
    );
    let merged = alp(&["batch", "--merge", s(&sharded)]);
    assert!(merged.status.success(), "{}", String::from_utf8_lossy(&merged.stderr));
    assert_eq!(statuses(&sharded.join("summary.jsonl")), expected);
    assert!(
        std::fs::read_to_string(sharded.join("summary.csv"))
            .expect("csv")
            .starts_with("id,line,status")
    );
    for id in ["p0", "p1", "p2"] {
        for file in ["pose.json", "env.exr"] {
            let (a, b) = (whole.join(id).join(file), sharded.join(id).join(file));
            assert_eq!(
                std::fs::read(&a).expect("whole"),
                std::fs::read(&b).expect("sharded"),
                "{id}/{file}"
            );
        }
    }

    // A run killed before p2 finished: its folder is absent; --resume does p2 alone.
    std::fs::remove_dir_all(whole.join("p2")).expect("remove p2");
    let before = std::fs::metadata(whole.join("p0/pose.json"))
        .expect("p0")
        .modified()
        .expect("mtime");
    alp(&["batch", "--manifest", s(&manifest), "--out", s(&whole), "--resume"]);
    let after = statuses(&whole.join("summary-0-of-1.jsonl"));
    assert_eq!(
        after[expected.len()..].to_vec(),
        vec![
            pair("p0", "skipped"),
            pair("line 2", "failed"),
            pair("p1", "skipped"),
            pair("p2", "done"),
            pair("p1", "failed"),
            pair("p3", "failed"),
        ]
    );
    assert_eq!(
        std::fs::metadata(whole.join("p0/pose.json"))
            .expect("p0")
            .modified()
            .expect("mtime"),
        before
    );
    let merged = alp(&["batch", "--merge", s(&whole)]);
    assert!(merged.status.success());
    assert_eq!(
        statuses(&whole.join("summary.jsonl")),
        expected,
        "the merge keeps each photo's finishing run"
    );

    // Bad flags are named.
    let bad = alp(&[
        "batch",
        "--manifest",
        s(&manifest),
        "--out",
        s(&whole),
        "--shard",
        "2/2",
    ]);
    assert!(!bad.status.success() && String::from_utf8_lossy(&bad.stderr).contains("2/2"));
    let bad = alp(&["batch", "--merge", s(&dir.join("s0"))]);
    assert!(!bad.status.success() && String::from_utf8_lossy(&bad.stderr).contains("summary"));
    // A manifest that lists nothing, or is not text, is named; no folder is made.
    let (empty, garbage) = (dir.join("empty.jsonl"), dir.join("garbage.jsonl"));
    std::fs::write(&empty, "\n \n").expect("empty");
    std::fs::write(&garbage, [0xff, 0xfe, 0x00, 0x9f]).expect("garbage");
    for (manifest, rule) in [(&empty, "no photos"), (&garbage, "UTF-8")] {
        let nothing = dir.join("nothing");
        let bad = alp(&["batch", "--manifest", s(manifest), "--out", s(&nothing)]);
        let stderr = String::from_utf8_lossy(&bad.stderr);
        assert!(
            !bad.status.success() && stderr.contains(s(manifest)) && stderr.contains(rule),
            "{stderr}"
        );
        assert!(!nothing.exists(), "{rule}: an output folder was made");
    }
    std::fs::remove_dir_all(&dir).expect("clean up");
}

#[test]
fn a_box_may_stand_for_the_mask_and_the_photo_s_exif_for_the_camera_file() {
    let dir = fresh_dir("alp-batch-box");
    let scene = dir.join("s0");
    synth_scene(&scene, "can", 0);
    // A box 3 px loose round the mask.
    let mask = render::image_io::Mask::read_png(scene.join("mask.png")).expect("mask");
    let [x0, y0, x1, y1] = alp::study::perturb::probe_box(&mask, [3.0; 4]).expect("a probe");
    let probe_box = format!("{x0},{y0},{x1},{y1}");
    let lines = [
        format!(
            r#"{{"id": "boxed", "image": "s0/image.exr", "box": "{probe_box}", "camera": "s0/camera.json", "probe": "can", "quality": "fast"}}"#
        ),
        format!(
            r#"{{"id": "both", "image": "s0/image.exr", "mask": "s0/mask.png", "box": "{probe_box}", "camera": "s0/camera.json", "probe": "can"}}"#
        ),
        r#"{"id": "no-camera", "image": "s0/image.exr", "mask": "s0/mask.png", "probe": "can"}"#.to_string(),
        r#"{"id": "bad-box", "image": "s0/image.exr", "box": "5,5,2,2", "camera": "s0/camera.json", "probe": "can"}"#
            .to_string(),
    ];
    let manifest = dir.join("manifest.jsonl");
    std::fs::write(&manifest, lines.join("\n") + "\n").expect("manifest");
    let out = dir.join("out");
    let run = alp(&["batch", "--manifest", s(&manifest), "--out", s(&out), "--threads", "2"]);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert_eq!(
        statuses(&out.join("summary-0-of-1.jsonl")),
        vec![
            pair("boxed", "done"),
            pair("both", "failed"),
            pair("no-camera", "failed"),
            pair("bad-box", "failed")
        ],
        "{stderr}"
    );
    // Each failure names its rule: both marks, the missing EXIF, the box field.
    for rule in ["not both", "--camera", "field `box`"] {
        assert!(stderr.contains(rule), "{rule}: {stderr}");
    }
    for file in ["mask_found.png", "camera.json", "pose.json", "env.exr"] {
        assert!(out.join("boxed").join(file).exists(), "{file}");
    }
    for id in ["both", "no-camera", "bad-box"] {
        assert!(!out.join(id).exists(), "{id}: a failed photo left a folder");
    }
    std::fs::remove_dir_all(&dir).expect("clean up");
}
