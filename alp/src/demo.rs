//! `alp demo`: the newcomer's first run, on data built into the binary.
//!
//! A photo of the procedural soda can standing on the ground under the
//! bundled courtyard map (the map behind it, the can's shadow on the ground:
//! the can rendered in by [`insert`]), the estimate of the can's pose and the
//! lighting from the photo alone, the evaluation's spheres relit under the
//! estimate and the truth, and a white sphere inserted beside the can under
//! each; `index.html` shows them side by side, `report.json` holds the scores.

use std::path::Path;
use std::time::Instant;

use glam::{Quat, Vec2, Vec3};
use serde::Serialize;

use render::RenderError;
use render::camera::Camera;
use render::envmap::EnvMap;
use render::image_io::{Mask, RgbImage};
use render::pose::Pose;

use crate::error::Result;
use crate::estimate::{Estimate, Photo, Quality, Settings, estimate};
use crate::eval::{PoseErrors, SphereErrors, compare_spheres, pose_errors};
use crate::insert::{Finish, Ground, InsertSettings, MaterialSpec, VirtualObject, insert};
use crate::relight::{RelightSettings, RelitSpheres, evaluation_region, relight};
use crate::synth::SynthScene;

/// The bundled files the demo starts from (`assets/`).
const ENV_EXR: &[u8] = include_bytes!("../../assets/envmaps/courtyard.exr");
const CAMERA_JSON: &[u8] = include_bytes!("../../assets/demo/camera.json");
const POSE_JSON: &[u8] = include_bytes!("../../assets/demo/pose.json");

/// The probe of the demo.
const PROBE: &str = "can";

/// Samples per pixel of the photo, and of the insertions.
const RENDER_SPP: u32 = 64;
/// Samples per pixel of the relit spheres (a square): a quarter of the
/// evaluation's (`relight::DEFAULT_SPP`), for the demo's time.
const RELIGHT_SPP: u32 = 256;
/// The inserted sphere: beside the can (metres, in the can's ground plane),
/// white diffuse.
const SPHERE_OFFSET: Vec2 = Vec2::new(0.085, 0.03);
const SPHERE_RADIUS: f32 = 0.03;
const SPHERE_ALBEDO: f32 = 0.8;

/// What `report.json` holds.
#[derive(Serialize)]
pub struct DemoReport {
    /// Relighting errors of the estimated map, per sphere.
    pub mirror: SphereErrors,
    /// See `mirror`.
    pub shiny: SphereErrors,
    /// See `mirror`.
    pub diffuse: SphereErrors,
    /// The estimated pose against the truth.
    pub pose: PoseErrors,
    /// The estimate's PSNR against the photo, dB.
    pub psnr_db: f64,
    /// Wall time of each step, seconds.
    pub wall_s: StepTimes,
}

/// Wall time of each step, seconds.
#[derive(Serialize)]
pub struct StepTimes {
    /// Rendering the photo.
    pub photo: f64,
    /// The estimate.
    pub estimate: f64,
    /// Relighting the spheres under both maps.
    pub relight: f64,
    /// Both insertions.
    pub insert: f64,
}

/// Runs the demo into `out` (written whole or not at all) and returns its report.
pub fn run(out: &Path) -> Result<DemoReport> {
    let mut report = None;
    crate::output::write_folder_atomically(out, |dir| {
        report = Some(run_into(dir)?);
        Ok(())
    })?;
    Ok(report.expect("written"))
}

fn write_bytes(path: &Path, bytes: &[u8]) -> Result<()> {
    std::fs::write(path, bytes).map_err(|e| RenderError::io(path, "write", e).into())
}

fn run_into(dir: &Path) -> Result<DemoReport> {
    // The bundled inputs, read back by the usual readers.
    let inputs = dir.join("inputs");
    std::fs::create_dir_all(&inputs).map_err(|e| RenderError::io(&inputs, "create folder", e))?;
    write_bytes(&inputs.join("courtyard.exr"), ENV_EXR)?;
    write_bytes(&inputs.join("camera.json"), CAMERA_JSON)?;
    write_bytes(&inputs.join("pose.json"), POSE_JSON)?;
    let env = EnvMap::read(inputs.join("courtyard.exr"))?;
    let camera = Camera::read(inputs.join("camera.json"))?;
    let pose = Pose::read(inputs.join("pose.json"))?;
    std::fs::remove_dir_all(&inputs).map_err(|e| RenderError::io(&inputs, "remove", e))?;

    let clock = Instant::now();
    let can = VirtualObject::load(Path::new(PROBE), None)?;
    let backplate = backplate(&env, &camera);
    let render = |photo: &RgbImage, object: &VirtualObject, pose: &Pose, env: &EnvMap| {
        let settings = InsertSettings {
            spp: RENDER_SPP,
            seed: 0,
            ground: Ground::Auto,
        };
        insert(photo, env, &camera, object, pose, &settings)
    };
    let photo = render(&backplate, &can, &pose, &env)?;
    let mask = Mask::new(
        camera.width as usize,
        camera.height as usize,
        photo.coverage.iter().map(|&c| c >= 0.5).collect(),
    );
    let scene = SynthScene {
        image: photo.image.clone(),
        mask,
        camera,
        pose,
    };
    crate::synth::write_scene(&dir.join("scene"), &scene, &env, PROBE)?;
    let photo_s = clock.elapsed().as_secs_f64();

    let clock = Instant::now();
    let input = Photo::new(scene.image.clone(), scene.mask.clone(), camera)?;
    let result = estimate(&input, &can.asset, &Settings::new(Quality::Default))?;
    let estimate_dir = dir.join("estimate");
    std::fs::create_dir_all(&estimate_dir).map_err(|e| RenderError::io(&estimate_dir, "create folder", e))?;
    crate::output::write_estimate(&estimate_dir, &input, &result)?;
    let estimate_s = clock.elapsed().as_secs_f64();

    let clock = Instant::now();
    let settings = RelightSettings {
        spp: RELIGHT_SPP,
        seed: 0,
    };
    let (spheres_estimate, spheres_truth) = (
        relight(&result.env, &camera, &settings)?,
        relight(&env, &camera, &settings)?,
    );
    let [mirror, shiny, diffuse] = compare_spheres(&spheres_estimate, &spheres_truth, &evaluation_region());
    let relight_s = clock.elapsed().as_secs_f64();

    let clock = Instant::now();
    let material = MaterialSpec {
        finish: Finish::Diffuse,
        albedo: Some([SPHERE_ALBEDO; 3]),
        roughness: None,
    };
    let sphere = VirtualObject::load(Path::new("sphere"), Some(&material))?;
    let ground_y = photo.ground_y.unwrap_or(0.0);
    let at = pose.translation + Vec3::new(SPHERE_OFFSET.x, 0.0, SPHERE_OFFSET.y);
    let sphere_pose = Pose::new(
        Quat::IDENTITY,
        SPHERE_RADIUS / crate::probes::SPHERE_RADIUS,
        Vec3::new(at.x, ground_y + SPHERE_RADIUS, at.z),
    );
    let inserted_estimate = render(&scene.image, &sphere, &sphere_pose, &result.env)?;
    let inserted_truth = render(&scene.image, &sphere, &sphere_pose, &env)?;
    let insert_s = clock.elapsed().as_secs_f64();

    let report = DemoReport {
        mirror,
        shiny,
        diffuse,
        pose: pose_errors(&result.pose, &pose),
        psnr_db: result.report.psnr_db,
        wall_s: StepTimes {
            photo: photo_s,
            estimate: estimate_s,
            relight: relight_s,
            insert: insert_s,
        },
    };
    let figures = Figures {
        result: &result,
        truth: &env,
        spheres: [&spheres_estimate, &spheres_truth],
        inserted: [&inserted_estimate.image, &inserted_truth.image],
        photo: &scene.image,
    };
    figures.write(dir)?;
    sphere_pose.write(dir.join("inserted_pose.json"))?;
    let json =
        serde_json::to_string_pretty(&report).map_err(|e| RenderError::io(dir.join("report.json"), "serialise", e))?;
    write_bytes(&dir.join("report.json"), (json + "\n").as_bytes())?;
    write_bytes(&dir.join("index.html"), index_html(&report).as_bytes())?;
    Ok(report)
}

/// The map seen through the camera: the background of the photo.
fn backplate(env: &EnvMap, camera: &Camera) -> RgbImage {
    let pixels = (0..camera.pixel_count())
        .map(|p| {
            let (row, col) = (p as u32 / camera.width, p as u32 % camera.width);
            env.lookup(camera.primary_ray(row, col, Vec2::splat(0.5)).1)
        })
        .collect();
    RgbImage::new(camera.width as usize, camera.height as usize, pixels)
}

/// The images `index.html` shows.
struct Figures<'a> {
    result: &'a Estimate,
    truth: &'a EnvMap,
    spheres: [&'a RelitSpheres; 2],
    inserted: [&'a RgbImage; 2],
    photo: &'a RgbImage,
}

impl Figures<'_> {
    fn write(&self, dir: &Path) -> Result<()> {
        self.photo.write_png_preview(dir.join("photo.png"), 0.0)?;
        self.result.rerender.write_png_preview(dir.join("rerender.png"), 0.0)?;
        self.result
            .env
            .to_image()
            .write_png_preview(dir.join("env_estimate.png"), 0.0)?;
        self.truth
            .downsample(self.result.env.height())
            .to_image()
            .write_png_preview(dir.join("env_truth.png"), 0.0)?;
        self.result
            .confidence
            .to_image()
            .write_png_preview(dir.join("confidence.png"), 0.0)?;
        self.spheres[0]
            .side_by_side()
            .write_png_preview(dir.join("spheres_estimate.png"), 0.0)?;
        self.spheres[1]
            .side_by_side()
            .write_png_preview(dir.join("spheres_truth.png"), 0.0)?;
        self.inserted[0].write_exr(dir.join("inserted_estimate.exr"))?;
        self.inserted[0].write_png_preview(dir.join("inserted_estimate.png"), 0.0)?;
        self.inserted[1].write_png_preview(dir.join("inserted_truth.png"), 0.0)?;
        Ok(())
    }
}

/// The one page: each figure under the estimate beside the truth, and the scores.
fn index_html(report: &DemoReport) -> String {
    let row = |title: &str, estimate: &str, truth: &str| {
        format!(
            "<h2>{title}</h2>\n<div class=\"row\"><figure><img src=\"{estimate}\"><figcaption>estimate</figcaption></figure>\
             <figure><img src=\"{truth}\"><figcaption>truth</figcaption></figure></div>\n"
        )
    };
    let sphere = |name: &str, e: &SphereErrors| {
        format!(
            "<tr><td>{name}</td><td>{:.2}</td><td>{:.3}</td></tr>",
            e.angular_deg, e.si_rmse
        )
    };
    format!(
        "<!doctype html>\n<html><head><meta charset=\"utf-8\"><title>alp demo</title>\n<style>\
         body{{font-family:sans-serif;max-width:1400px;margin:1em auto;background:#222;color:#ddd}}\
         .row{{display:flex;gap:1em;flex-wrap:wrap}} figure{{margin:0}} img{{max-width:680px;image-rendering:auto}}\
         td,th{{padding:0.2em 1em;text-align:right}}</style></head><body>\n\
         <h1>Accidental light probe: lighting from a photo of a soda can</h1>\n\
         <p>The photo (a synthetic can under the courtyard map), its re-render from the estimated pose and \
         lighting, the maps, the evaluation's spheres relit and a white sphere inserted into the photo, \
         under the estimate and under the truth.</p>\n\
         <div class=\"row\"><figure><img src=\"photo.png\"><figcaption>photo</figcaption></figure>\
         <figure><img src=\"rerender.png\"><figcaption>re-render from the estimate (PSNR {psnr:.1} dB)</figcaption></figure></div>\n\
         {maps}<h2>Confidence</h2>\n<p>How well the can sees each direction of the map (white: well).</p>\
         <img src=\"confidence.png\">\n{spheres}{inserted}\
         <h2>Scores</h2>\n<table><tr><th>sphere</th><th>angular error (deg)</th><th>si-RMSE</th></tr>{mirror}{shiny}{diffuse}</table>\n\
         <p>Pose: rotation {rot:.2} deg, axis {axis:.2} deg, translation {trans:.1} mm, scale ratio {scale:.4}.</p>\n\
         <p>Wall time: photo {t_photo:.1} s, estimate {t_est:.1} s, relighting {t_rel:.1} s, insertion {t_ins:.1} s.</p>\n\
         </body></html>\n",
        psnr = report.psnr_db,
        maps = row("Environment map", "env_estimate.png", "env_truth.png"),
        spheres = row(
            "Relit spheres: mirror, shiny, diffuse",
            "spheres_estimate.png",
            "spheres_truth.png"
        ),
        inserted = row(
            "A white sphere inserted into the photo",
            "inserted_estimate.png",
            "inserted_truth.png"
        ),
        mirror = sphere("mirror", &report.mirror),
        shiny = sphere("shiny", &report.shiny),
        diffuse = sphere("diffuse", &report.diffuse),
        rot = report.pose.rotation_deg,
        axis = report.pose.axis_deg,
        trans = report.pose.translation_mm,
        scale = report.pose.scale_ratio,
        t_photo = report.wall_s.photo,
        t_est = report.wall_s.estimate,
        t_rel = report.wall_s.relight,
        t_ins = report.wall_s.insert,
    )
}
