//! Round trips of every file format of FORMATS.md, and the errors on broken files: each message
//! must name the file and the rule broken.

use std::path::{Path, PathBuf};

use exr::prelude::{
    AnyChannel, AnyChannels, Encoding, FlatSamples, Image, Layer, LayerAttributes, SmallVec, WritableImage,
};
use glam::{Mat4, Quat, Vec2, Vec3};
use render::camera::Camera;
use render::envmap::EnvMap;
use render::image_io::{Mask, RgbImage, read_image_and_mask};
use render::pose::Pose;
use render::probe::ProbeAsset;
use render::procedural::{SodaCan, ThermosCap};
use render::sampling::Rng;

/// A fresh, empty folder for one test.
fn temp_dir(test: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("render-formats-{}-{test}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

/// Asserts that `result` failed with a message naming `file` and containing `rule`.
fn assert_error<T: std::fmt::Debug>(result: render::Result<T>, file: &str, rule: &str) {
    let message = result.expect_err("should have failed").to_string();
    assert!(message.contains(file), "message does not name {file}: {message}");
    assert!(message.contains(rule), "message does not say `{rule}`: {message}");
}

fn random_image(width: usize, height: usize, seed: u64) -> RgbImage {
    let mut rng = Rng::new(seed, 0);
    let pixels = (0..width * height)
        .map(|_| [rng.next_f32() * 10.0, rng.next_f32(), rng.next_f32() * 1e-3])
        .collect();
    RgbImage::new(width, height, pixels)
}

/// Writes an EXR with arbitrary named f32 channels.
fn write_channels(path: &Path, width: usize, height: usize, names: &[&str], value: f32) {
    let list: Vec<AnyChannel<FlatSamples>> = names
        .iter()
        .map(|n| AnyChannel::new(*n, FlatSamples::F32(vec![value; width * height])))
        .collect();
    let layer = Layer::new(
        (width, height),
        LayerAttributes::default(),
        Encoding::SMALL_LOSSLESS,
        AnyChannels::sort(SmallVec::from_vec(list)),
    );
    Image::from_layer(layer).write().to_file(path).expect("write test EXR");
}

#[test]
fn env_map_round_trip_is_exact() {
    let dir = temp_dir("env_round_trip");
    let image = random_image(64, 32, 1);
    let env = EnvMap::new(64, 32, image.pixels).unwrap();
    let path = dir.join("env.exr");
    env.write(&path).unwrap();
    assert_eq!(EnvMap::read(&path).unwrap(), env);
}

#[test]
fn real_env_maps_load() {
    for name in ["courtyard", "studio", "sunset"] {
        let env = EnvMap::read(format!("{}/../assets/envmaps/{name}.exr", env!("CARGO_MANIFEST_DIR"))).unwrap();
        assert_eq!((env.width(), env.height()), (1024, 512));
        assert!(env.radiance().iter().flatten().all(|v| v.is_finite() && *v >= 0.0));
    }
}

#[test]
fn broken_env_maps_are_rejected() {
    let dir = temp_dir("env_errors");
    let path = dir.join("env.exr");
    random_image(300, 128, 2).write_exr(&path).unwrap();
    assert_error(EnvMap::read(&path), "env.exr", "width 300 is not 2 x height 128");

    let mut image = random_image(16, 8, 3);
    image.pixels[20][1] = f32::NAN;
    image.write_exr(&path).unwrap();
    assert_error(
        RgbImage::read_exr(&path),
        "env.exr",
        "(row 1, col 4) channel G = NaN is not finite",
    );
    assert_error(EnvMap::read(&path), "env.exr", "is not finite");

    let mut image = random_image(16, 8, 4);
    image.pixels[17][0] = f32::INFINITY;
    image.write_exr(&path).unwrap();
    assert_error(EnvMap::read(&path), "env.exr", "channel R = inf");

    let mut image = random_image(16, 8, 5);
    image.pixels[3][2] = -1.0;
    image.write_exr(&path).unwrap();
    assert_error(
        EnvMap::read(&path),
        "env.exr",
        "(row 0, col 3) channel B = -1 is not finite and >= 0",
    );

    write_channels(&path, 16, 8, &["R", "G"], 1.0);
    assert_error(
        EnvMap::read(&path),
        "env.exr",
        "missing channels: need R, G and B (or a single channel), found [G, R]",
    );

    std::fs::write(&path, b"not an exr").unwrap();
    assert_error(EnvMap::read(&path), "env.exr", "cannot read OpenEXR");
}

#[test]
fn small_compression_ringing_is_clamped_not_rejected() {
    let dir = temp_dir("env_ringing");
    let path = dir.join("env.exr");
    let mut image = RgbImage::filled(16, 8, [1.0; 3]);
    image.pixels[0] = [100.0; 3];
    image.pixels[1][0] = -0.05;
    image.write_exr(&path).unwrap();
    assert_eq!(EnvMap::read(&path).unwrap().texel(0, 1), [0.0, 1.0, 1.0]);
}

#[test]
fn half_and_single_channel_exr_read_as_rgb() {
    let dir = temp_dir("half");
    let path = dir.join("half.exr");
    let channels = exr::prelude::SpecificChannels::rgb(|exr::math::Vec2(x, _y): exr::math::Vec2<usize>| {
        (
            exr::prelude::f16::from_f32(x as f32 * 0.5),
            exr::prelude::f16::from_f32(2.0),
            exr::prelude::f16::from_f32(0.25),
        )
    });
    let layer = Layer::new((4, 2), LayerAttributes::default(), Encoding::SMALL_LOSSLESS, channels);
    Image::from_layer(layer).write().to_file(&path).unwrap();
    let image = RgbImage::read_exr(&path).unwrap();
    assert_eq!(image.get(1, 3), [1.5, 2.0, 0.25]);

    write_channels(&path, 4, 2, &["Y"], 0.5);
    assert_eq!(RgbImage::read_exr(&path).unwrap().get(0, 0), [0.5; 3]);
}

#[test]
fn masks_round_trip_and_check_sizes() {
    let dir = temp_dir("masks");
    let inside: Vec<bool> = (0..12 * 5).map(|i| i % 3 == 0).collect();
    let mask = Mask::new(12, 5, inside);
    let mask_path = dir.join("mask.png");
    mask.write_png(&mask_path).unwrap();
    assert_eq!(Mask::read_png(&mask_path).unwrap(), mask);

    // Values > 127 are the probe.
    image::save_buffer(&mask_path, &[0, 127, 128, 255], 4, 1, image::ExtendedColorType::L8).unwrap();
    assert_eq!(
        Mask::read_png(&mask_path).unwrap().inside,
        vec![false, false, true, true]
    );

    let image_path = dir.join("image.exr");
    RgbImage::filled(12, 6, [1.0; 3]).write_exr(&image_path).unwrap();
    mask.write_png(&mask_path).unwrap();
    assert_error(
        read_image_and_mask(&image_path, &mask_path),
        "mask.png",
        "mask size 12x5 differs from image",
    );
    assert_error(read_image_and_mask(&image_path, &mask_path), "image.exr", "size 12x6");

    // Colour masks count by their grey value; 16-bit ones are refused.
    image::save_buffer(&mask_path, &[0; 12], 2, 2, image::ExtendedColorType::Rgb8).unwrap();
    assert_eq!(Mask::read_png(&mask_path).unwrap().inside, vec![false; 4]);
    image::save_buffer(&mask_path, &[0; 8], 2, 2, image::ExtendedColorType::L16).unwrap();
    assert_error(
        Mask::read_png(&mask_path),
        "mask.png",
        "a mask must have 8 bits per channel",
    );
}

#[test]
fn preview_png_is_exposed_clamped_and_srgb_encoded() {
    let dir = temp_dir("preview");
    let path = dir.join("preview.png");
    RgbImage::new(3, 1, vec![[0.09, 0.18, 0.0], [4.0, -1.0, f32::NAN], [0.0; 3]])
        .write_png_preview(&path, 1.0)
        .unwrap();
    let png = image::open(&path).unwrap().to_rgb8();
    // 0.09 and 0.18 exposed by one stop: 0.18 encodes to 118, 0.36 to 162.
    assert_eq!(png.get_pixel(0, 0).0, [118, 162, 0]);
    assert_eq!(png.get_pixel(1, 0).0, [255, 0, 0]);
}

#[test]
fn camera_round_trip_and_errors() {
    let dir = temp_dir("camera");
    let path = dir.join("camera.json");
    let camera = Camera::new(
        640,
        480,
        40.0,
        Vec3::new(0.0, 0.1, 0.5),
        Vec3::new(0.0, 0.06, 0.0),
        Vec3::Y,
    )
    .unwrap();
    camera.write(&path).unwrap();
    assert_eq!(Camera::read(&path).unwrap(), camera);

    let write = |text: &str| std::fs::write(&path, text).unwrap();
    write(
        r#"{"width": 640, "height": 480, "fov_y_deg": 190.0, "origin": [0, 0.1, 0.5], "target": [0, 0.06, 0], "up": [0, 1, 0]}"#,
    );
    assert_error(
        Camera::read(&path),
        "camera.json",
        "field `fov_y_deg`: value 190 outside (0, 180)",
    );
    write(
        r#"{"width": 640, "height": 0, "fov_y_deg": 40.0, "origin": [0, 0.1, 0.5], "target": [0, 0.06, 0], "up": [0, 1, 0]}"#,
    );
    assert_error(Camera::read(&path), "camera.json", "640x0 must be > 0");
    write(
        r#"{"width": 640, "height": 480, "fov_y_deg": 40.0, "origin": [0, 0.1, 0.5], "target": [0, 0.1, 0.5], "up": [0, 1, 0]}"#,
    );
    assert_error(Camera::read(&path), "camera.json", "field `target`: equals origin");
    write(
        r#"{"width": 640, "height": 480, "fov_y_deg": 40.0, "origin": [0, 1, 0], "target": [0, 0, 0], "up": [0, 1, 0]}"#,
    );
    assert_error(Camera::read(&path), "camera.json", "field `up`");
    write(r#"{"width": 640, "height": 480, "fov_y_deg": 40.0, "origin": [0, 0.1, 0.5], "target": [0, 0.06, 0]}"#);
    assert_error(Camera::read(&path), "camera.json", "missing field `up`");
}

#[test]
fn pose_round_trip_and_errors() {
    let dir = temp_dir("pose");
    let path = dir.join("pose.json");
    let pose = Pose::new(Quat::from_axis_angle(Vec3::Y, 0.4), 1.5, Vec3::new(0.1, 0.0, -0.2));
    pose.write(&path).unwrap();
    let back = Pose::read(&path).unwrap();
    assert!(back.to_world().abs_diff_eq(pose.to_world(), 1e-6));

    std::fs::write(&path, r#"{"to_world": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}"#).unwrap();
    assert_eq!(Pose::read(&path).unwrap(), Pose::IDENTITY);
    std::fs::write(&path, r#"{"to_world": [[2,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}"#).unwrap();
    assert_error(
        Pose::read(&path),
        "pose.json",
        "field `to_world`: non-uniform scale or shear",
    );
    std::fs::write(&path, r#"{"to_world": [[1,0.5,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}"#).unwrap();
    assert_error(Pose::read(&path), "pose.json", "non-uniform scale or shear");
    std::fs::write(&path, r#"{"to_world": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,1,1]]}"#).unwrap();
    assert_error(
        Pose::read(&path),
        "pose.json",
        "last row [0.0, 0.0, 1.0, 1.0] is not [0, 0, 0, 1]",
    );
    std::fs::write(&path, r#"{"to_world": [[1,0,0,0],[0,1,0,0],[0,0,1,0]]}"#).unwrap();
    assert_error(Pose::read(&path), "pose.json", "cannot parse JSON");
    let m = Mat4::from_scale(Vec3::new(1.0, 1.0, 0.0));
    assert!(Pose::from_matrix(m).unwrap_err().to_string().contains("singular"));
}

#[test]
fn probe_folder_round_trip() {
    let dir = temp_dir("probe_round_trip");
    for probe in [SodaCan::default().build(), ThermosCap::default().build()] {
        let folder = dir.join(&probe.name);
        probe.write(&folder).unwrap();
        let back = ProbeAsset::read(&folder).unwrap();
        assert!(back.name == probe.name && back.albedo == probe.albedo && back.roughness == probe.roughness);
        assert!(back.visibility == probe.visibility);
        // tobj renumbers vertices in face order and drops unused ones: compare triangle by triangle.
        // Rust prints the shortest decimal that reads back bit-identically, so the OBJ is exact.
        let (a, b) = (&probe.mesh, &back.mesh);
        assert_eq!(a.triangles.len(), b.triangles.len());
        for (ta, tb) in a.triangles.iter().zip(&b.triangles) {
            for (&i, &j) in ta.iter().zip(tb) {
                let (i, j) = (i as usize, j as usize);
                assert!(
                    a.positions[i] == b.positions[j] && a.uvs[i] == b.uvs[j],
                    "{}: vertex {i} differs",
                    probe.name
                );
                assert!(
                    a.normals[i].abs_diff_eq(b.normals[j], 1e-6),
                    "{}: normal {i} differs",
                    probe.name
                );
            }
        }
    }
}

/// A one-triangle probe folder with the given OBJ text and probe.json fields.
fn small_probe(dir: &Path, obj: &str, json: &str) {
    std::fs::write(dir.join("mesh.obj"), obj).unwrap();
    std::fs::write(dir.join("probe.json"), json).unwrap();
}

const TRIANGLE_OBJ: &str = "mtllib missing.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n";

#[test]
fn probe_constants_and_defaults() {
    let dir = temp_dir("probe_constants");
    small_probe(
        &dir,
        TRIANGLE_OBJ,
        r#"{"name": "t", "mesh": "mesh.obj", "albedo": [0.9, 0.8, 0.7], "roughness": 0.1}"#,
    );
    let probe = ProbeAsset::read(&dir).unwrap();
    let m = probe.material(Vec2::new(0.3, 0.3));
    assert_eq!((m.albedo, m.roughness, m.visibility), ([0.9, 0.8, 0.7], 0.1, 1.0));
    // No vn in the file: normals computed, +Z for this counter-clockwise triangle.
    assert!(probe.mesh.normals.iter().all(|n| n.abs_diff_eq(Vec3::Z, 1e-6)));
}

#[test]
fn broken_probes_are_rejected() {
    let dir = temp_dir("probe_errors");
    let json = |extra: &str| format!(r#"{{"name": "t", "mesh": "mesh.obj", "albedo": [0.9, 0.9, 0.9], {extra}}}"#);
    small_probe(&dir, TRIANGLE_OBJ, &json(r#""roughness": 1.7"#));
    assert_error(
        ProbeAsset::read(&dir),
        "probe.json",
        "field `roughness`: value 1.7 outside [0, 1]",
    );

    small_probe(&dir, TRIANGLE_OBJ, &json(r#""roughness": "rough.exr""#));
    let mut rough = RgbImage::filled(4, 4, [0.5; 3]);
    rough.pixels[5][0] = 1.5;
    rough.write_exr(dir.join("rough.exr")).unwrap();
    assert_error(
        ProbeAsset::read(&dir),
        "rough.exr",
        "field `roughness`: texel (row 1, col 1) channel R = 1.5 outside [0, 1]",
    );

    small_probe(&dir, TRIANGLE_OBJ, &json(r#""roughness": 0.2, "visibility": -0.5"#));
    assert_error(
        ProbeAsset::read(&dir),
        "probe.json",
        "field `visibility`: value -0.5 outside [0, 1]",
    );

    small_probe(
        &dir,
        TRIANGLE_OBJ,
        &json(r#""roughness": 0.2, "visibility": "nowhere.exr""#),
    );
    assert_error(ProbeAsset::read(&dir), "nowhere.exr", "cannot read OpenEXR");

    small_probe(
        &dir,
        TRIANGLE_OBJ,
        r#"{"name": "t", "mesh": "mesh.obj", "albedo": [1.2, 0.9, 0.9], "roughness": 0.2}"#,
    );
    assert_error(
        ProbeAsset::read(&dir),
        "probe.json",
        "field `albedo`: value 1.2 outside [0, 1]",
    );

    small_probe(
        &dir,
        TRIANGLE_OBJ,
        r#"{"name": "t", "mesh": "mesh.obj", "albedo": [0.9, 0.9], "roughness": 0.2}"#,
    );
    assert_error(
        ProbeAsset::read(&dir),
        "probe.json",
        "field `albedo`: [0.9,0.9] is neither a texture file path",
    );

    small_probe(
        &dir,
        TRIANGLE_OBJ,
        r#"{"mesh": "mesh.obj", "albedo": 0.9, "roughness": 0.2}"#,
    );
    assert_error(ProbeAsset::read(&dir), "probe.json", "field `name`: missing (required)");

    small_probe(&dir, TRIANGLE_OBJ, &json(r#""roughness": 0.2, "roughnes": 0.3"#));
    assert_error(ProbeAsset::read(&dir), "probe.json", "field `roughnes`: unknown field");

    small_probe(
        &dir,
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
        &json(r#""roughness": 0.2"#),
    );
    assert_error(ProbeAsset::read(&dir), "mesh.obj", "no texture coordinates (`vt`)");

    small_probe(&dir, "# nothing\n", &json(r#""roughness": 0.2"#));
    assert_error(ProbeAsset::read(&dir), "mesh.obj", "mesh has no triangles");

    std::fs::write(dir.join("probe.json"), "{not json").unwrap();
    assert_error(ProbeAsset::read(&dir), "probe.json", "cannot parse JSON");
}
