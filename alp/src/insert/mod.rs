//! Virtual object insertion (the paper's Fig. 1): an object rendered under an
//! estimated env map into the photo the map came from, with the shadow it
//! casts on a ground plane, by differential rendering (Debevec 1998).
//!
//! The object is rendered by the probe renderer ([`render_layer`]: MIS of the
//! BSDF and the map, self-shadowing, one bounce on itself) and laid over the
//! photo with its sub-pixel coverage. The ground is a horizontal plane that
//! catches shadows: for a diffuse plane under distant light, its radiance
//! with the object over its radiance without is the ratio of irradiances
//!
//!   E_with(x) / E = 1 - E_blocked(x) / E,
//!
//! whatever the plane's albedo, so multiplying the photo's ground pixels by it
//! is Debevec's differential render with the albedo each pixel implies (the
//! ground's texture stays, darkened). E, the map's irradiance on an upward
//! plane, is a quadrature over the map's texels (the same at every point).
//! Where the object blocks the map it also sends light of its own, so the
//! plane's irradiance with it is E - E_blocked + E_bounce; both are Monte
//! Carlo estimates per pixel over directions drawn half from the map and half
//! from the cosine (balance heuristic: a sun's sharp shadow and the soft
//! contact shadow both converge), the object's light by render's point
//! shading ([`ShadingPoint`]: a BSDF and a map sample, shadowed by the object). (A white object on a grey floor gives back a third to
//! a half of the light it blocks: the path-traced reference of the tests.)
//!
//! Left out: the plane seen by the object (the map's lower half stands in for
//! it, in its render and in the light it sends to the plane).

use std::path::Path;

use glam::{Vec2, Vec3};
use rayon::prelude::*;
use serde::Deserialize;

use render::RenderError;
use render::accel::Accel;
use render::bsdf::{GgxMetal, Lambertian, Mirror, PointSurface, Reflectance};
use render::camera::Camera;
use render::envmap::EnvMap;
use render::image_io::RgbImage;
use render::integrator::{RenderSettings, ShadingPoint, render_layer};
use render::mesh::{Mesh, Uvs};
use render::pose::Pose;
use render::probe::{ProbeAsset, Texture};
use render::sampling::{EnvSampler, Frame, Rng, cosine_hemisphere_pdf, sample_cosine_hemisphere, stratified_square};

use crate::error::{Error, Result};

pub mod cli;

/// The reflectance model of an inserted object.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Finish {
    /// Lambertian, with the albedo as its diffuse albedo.
    Diffuse,
    /// The probes' GGX metal (albedo = Schlick's F0, roughness r, alpha = r^2).
    Metal,
    /// A perfect mirror of reflectance = albedo.
    Mirror,
}

impl Finish {
    /// The finishes by name, for messages.
    pub const NAMES: &str = "diffuse, metal, mirror";

    /// The finish named `name`.
    pub fn parse(name: &str) -> Option<Self> {
        match name {
            "diffuse" => Some(Finish::Diffuse),
            "metal" => Some(Finish::Metal),
            "mirror" => Some(Finish::Mirror),
            _ => None,
        }
    }

    /// The BSDF that renders it, on the tape and at points (the light the
    /// object sends the ground).
    pub fn bsdf(self) -> &'static dyn Reflectance {
        match self {
            Finish::Diffuse => &Lambertian,
            Finish::Metal => &GgxMetal,
            Finish::Mirror => &Mirror,
        }
    }
}

/// A material given to an object: the file of `--material FILE.json`, or
/// the command line's `--material KIND [--albedo] [--roughness]`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialSpec {
    /// `diffuse`, `metal` or `mirror`.
    #[serde(rename = "type")]
    pub finish: Finish,
    /// Linear RGB in [0, 1] (one number: grey); default 0.8.
    #[serde(default, deserialize_with = "albedo_field")]
    pub albedo: Option<[f32; 3]>,
    /// GGX roughness in [0, 1], metal only; default 0.3.
    #[serde(default)]
    pub roughness: Option<f32>,
}

/// An albedo field: a number (grey) or `[r, g, b]`.
fn albedo_field<'de, D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Option<[f32; 3]>, D::Error> {
    #[derive(Deserialize)]
    #[serde(untagged)]
    enum Albedo {
        Grey(f32),
        Rgb([f32; 3]),
    }
    Ok(Some(match Albedo::deserialize(d)? {
        Albedo::Grey(v) => [v; 3],
        Albedo::Rgb(rgb) => rgb,
    }))
}

/// Albedo of a material that names none.
pub const DEFAULT_ALBEDO: f32 = 0.8;
/// Roughness of a metal that names none.
pub const DEFAULT_ROUGHNESS: f32 = 0.3;

impl MaterialSpec {
    /// Reads a material JSON file (`{"type": "metal", "albedo": [r, g, b], "roughness": 0.3}`).
    pub fn read(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| RenderError::io(path, "read", e))?;
        let spec: Self = serde_json::from_str(&text).map_err(|e| {
            Error::invalid(
                "material",
                format!("{e} (fields: type = {}, albedo, roughness)", Finish::NAMES),
            )
            .in_file(path)
        })?;
        spec.check().map_err(|e| e.in_file(path))?;
        Ok(spec)
    }

    /// Checks the values' ranges.
    pub fn check(&self) -> Result<()> {
        if let Some(a) = self.albedo
            && let Some(v) = a.iter().find(|v| !(0.0..=1.0).contains(*v))
        {
            return Err(Error::invalid("albedo", format!("{v} is outside [0, 1]")));
        }
        match self.roughness {
            Some(_) if self.finish != Finish::Metal => {
                Err(Error::invalid("roughness", "applies to a metal only (type = metal)"))
            }
            Some(r) if !(0.0..=1.0).contains(&r) => Err(Error::invalid("roughness", format!("{r} is outside [0, 1]"))),
            _ => Ok(()),
        }
    }

    /// `asset` with this material everywhere (its textures replaced by constants).
    fn apply(&self, mut asset: ProbeAsset) -> ProbeAsset {
        asset.albedo = Texture::constant(self.albedo.unwrap_or([DEFAULT_ALBEDO; 3]));
        let roughness = match self.finish {
            Finish::Metal => self.roughness.unwrap_or(DEFAULT_ROUGHNESS),
            Finish::Diffuse | Finish::Mirror => 0.0,
        };
        asset.roughness = Texture::constant([roughness; 3]);
        asset.visibility = Texture::constant([1.0; 3]);
        asset
    }
}

/// An object to insert: its shape (mesh frame, metres) and material.
#[derive(Clone, Debug)]
pub struct VirtualObject {
    /// The shape and the material's textures (constants unless a probe folder's).
    pub asset: ProbeAsset,
    /// The reflectance model.
    pub finish: Finish,
}

impl VirtualObject {
    /// `object`: a probe folder or procedural probe name (GGX metal with its
    /// own textures unless `material` overrides them), or an OBJ file, which
    /// needs a `material`.
    pub fn load(object: &Path, material: Option<&MaterialSpec>) -> Result<Self> {
        let is_obj = object.extension().is_some_and(|e| e.eq_ignore_ascii_case("obj"));
        let asset = if is_obj {
            let Some(_) = material else {
                return Err(Error::invalid(
                    "--material",
                    format!(
                        "an OBJ object needs a material: --material {} or FILE.json",
                        Finish::NAMES.replace(", ", "|")
                    ),
                ));
            };
            let mesh = Mesh::read_obj_with(object, Uvs::Optional)?;
            let name = object
                .file_stem()
                .map_or("object".into(), |s| s.to_string_lossy().into_owned());
            ProbeAsset {
                name,
                mesh,
                albedo: Texture::constant([1.0; 3]),
                roughness: Texture::constant([0.0; 3]),
                visibility: Texture::constant([1.0; 3]),
            }
        } else {
            crate::probes::load(object)?
        };
        Ok(match material {
            Some(m) => VirtualObject {
                asset: m.apply(asset),
                finish: m.finish,
            },
            None => VirtualObject {
                asset,
                finish: Finish::Metal,
            },
        })
    }
}

/// Where the shadow-catching ground plane lies.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Ground {
    /// Under the object: the plane through its lowest point.
    Auto,
    /// No plane: the object alone, no shadow.
    None,
    /// The plane y = this, world metres.
    Height(f32),
}

impl std::str::FromStr for Ground {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "auto" => Ok(Ground::Auto),
            "none" => Ok(Ground::None),
            _ => match s.parse::<f32>() {
                Ok(y) if y.is_finite() => Ok(Ground::Height(y)),
                _ => Err(format!("`{s}` is neither auto, none nor a height in metres")),
            },
        }
    }
}

/// How an insertion is rendered.
#[derive(Clone, Copy, Debug)]
pub struct InsertSettings {
    /// Samples per pixel of the object, and shadow samples per ground pixel.
    pub spp: u32,
    /// Random seed (same seed, same image, on any number of threads).
    pub seed: u64,
    /// The ground plane.
    pub ground: Ground,
}

impl Default for InsertSettings {
    fn default() -> Self {
        InsertSettings {
            spp: 64,
            seed: 0,
            ground: Ground::Auto,
        }
    }
}

/// The photo with the object in it.
#[derive(Clone, Debug)]
pub struct Insertion {
    /// The composite, linear RGB.
    pub image: RgbImage,
    /// Per pixel, the share of it the object covers.
    pub coverage: Vec<f32>,
    /// Per pixel, the ground's light with the object over its light without,
    /// RGB: below 1 in the shadow, above where the object reflects light onto
    /// the ground, 1 off the ground.
    pub shadow: Vec<[f32; 3]>,
    /// The ground plane's height, when there is one.
    pub ground_y: Option<f32>,
}

impl Insertion {
    /// Whether the object shows in the photo at all.
    pub fn object_visible(&self) -> bool {
        self.coverage.iter().any(|&c| c > 0.0)
    }
}

/// Renders `object` at `pose` under `env` into `photo`, seen by `camera`.
pub fn insert(
    photo: &RgbImage,
    env: &EnvMap,
    camera: &Camera,
    object: &VirtualObject,
    pose: &Pose,
    settings: &InsertSettings,
) -> Result<Insertion> {
    if (photo.width, photo.height) != (camera.width as usize, camera.height as usize) {
        return Err(Error::invalid(
            "image",
            format!(
                "the photo is {}x{} but the camera is {}x{}: they must match",
                photo.width, photo.height, camera.width, camera.height
            ),
        ));
    }
    if settings.spp == 0 {
        return Err(Error::invalid("spp", "needs at least one sample per pixel"));
    }
    // The object in the world, for the ground's rays (none without a ground).
    let posed = (settings.ground != Ground::None).then(|| PosedObject::new(object, pose));
    let ground_y = match (settings.ground, &posed) {
        (Ground::Auto, Some(posed)) => Some(posed.mesh.bounds().0.y),
        (Ground::Height(y), _) => Some(y),
        _ => None,
    };
    if let Some(y) = ground_y
        && camera.origin.y <= y
    {
        return Err(Error::invalid(
            "ground",
            format!(
                "the camera (y = {}) is not above the ground plane (y = {y}); give --ground none or a lower height",
                camera.origin.y
            ),
        ));
    }
    let render_settings = RenderSettings {
        spp: settings.spp,
        seed: settings.seed,
    };
    let (layer, coverage) = render_layer(&object.asset, pose, camera, env, object.finish.bsdf(), &render_settings);
    let shadow = match (ground_y, &posed) {
        (Some(y), Some(posed)) => ground_ratios(env, posed, camera, y, settings),
        _ => vec![[1.0; 3]; camera.pixel_count()],
    };
    let pixels = (0..camera.pixel_count())
        .map(|p| {
            let (under, a) = (photo.pixels[p], coverage[p]);
            std::array::from_fn(|c| layer.pixels[p][c] + (1.0 - a) * under[c] * shadow[p][c])
        })
        .collect();
    Ok(Insertion {
        image: RgbImage::new(photo.width, photo.height, pixels),
        coverage,
        shadow,
        ground_y,
    })
}

/// Offset of a ground ray's origin above the plane, metres.
const SHADOW_RAY_OFFSET: f32 = 1e-4;

/// The map's irradiance on an upward plane, RGB: its texels' radiance times
/// cosine times solid angle.
fn upward_irradiance(env: &EnvMap) -> [f64; 3] {
    let mut e = [0.0f64; 3];
    for row in 0..env.height() {
        let solid_angle = env.texel_solid_angle(row) as f64;
        for col in 0..env.width() {
            let cos = env.texel_direction(row, col).y.max(0.0) as f64;
            let l = env.texel(row, col);
            for c in 0..3 {
                e[c] += l[c] as f64 * cos * solid_angle;
            }
        }
    }
    e
}

/// Per pixel, `1 - (E_blocked - E_bounce) / E` on the plane y = `ground_y`
/// (the module's comment), from `settings.spp` samples at stratified points
/// of the pixel's footprint on the plane, each with one stratified
/// direction; pixel p's numbers come from stream p of the seed.
fn ground_ratios(
    env: &EnvMap,
    object: &PosedObject,
    camera: &Camera,
    ground_y: f32,
    settings: &InsertSettings,
) -> Vec<[f32; 3]> {
    let irradiance = upward_irradiance(env);
    let sampler = EnvSampler::new(env);
    let up = Frame::from_normal(Vec3::Y);
    let width = camera.width;
    let n = settings.spp as usize;
    (0..camera.pixel_count())
        .into_par_iter()
        .map(|p| {
            let (row, col) = (p as u32 / width, p as u32 % width);
            let mut rng = Rng::new(settings.seed, p as u64);
            let (mut offsets, mut directions) = (vec![Vec2::ZERO; n], vec![Vec2::ZERO; n]);
            stratified_square(&mut rng, &mut offsets);
            stratified_square(&mut rng, &mut directions);
            let mut change = [0.0f64; 3];
            for (k, (&offset, &u)) in offsets.iter().zip(&directions).enumerate() {
                let (origin, direction) = camera.primary_ray(row, col, offset);
                let t = (ground_y - origin.y) / direction.y;
                if direction.y >= 0.0 || !t.is_finite() {
                    continue;
                }
                // Alternate the strategies over the strata (both cover the square).
                let wi = if k % 2 == 0 {
                    sampler.sample(u).direction
                } else {
                    up.to_world(sample_cosine_hemisphere(u))
                };
                if wi.y <= 0.0 {
                    continue;
                }
                let point = origin + t * direction + SHADOW_RAY_OFFSET * Vec3::Y;
                let Some(reflected) = object.radiance_towards(point, wi, &mut rng, env, &sampler) else {
                    continue;
                };
                let pdf = 0.5 * sampler.pdf(wi) + 0.5 * cosine_hemisphere_pdf(up.to_local(wi));
                let l = env.lookup(wi);
                for c in 0..3 {
                    change[c] += ((l[c] - reflected[c]) * wi.y / pdf) as f64;
                }
            }
            std::array::from_fn(|c| {
                if irradiance[c] > 0.0 {
                    (1.0 - change[c] / (n as f64 * irradiance[c])).max(0.0) as f32
                } else {
                    1.0
                }
            })
        })
        .collect()
}

/// The object in the world, for the rays the ground sends.
struct PosedObject<'a> {
    object: &'a VirtualObject,
    mesh: Mesh,
    accel: Accel,
}

impl<'a> PosedObject<'a> {
    fn new(object: &'a VirtualObject, pose: &Pose) -> Self {
        let mesh = object.asset.mesh.posed(pose);
        let accel = Accel::new(&mesh);
        PosedObject { object, mesh, accel }
    }

    /// When the ray from `point` along `wi` meets the object: the radiance the
    /// object sends back along it, by one BSDF and one map sample
    /// ([`ShadingPoint`]; shadowed by the object itself, the ground not traced).
    fn radiance_towards(
        &self,
        point: Vec3,
        wi: Vec3,
        rng: &mut Rng,
        env: &EnvMap,
        sampler: &EnvSampler,
    ) -> Option<[f32; 3]> {
        let hit = self.accel.closest_hit(point, wi, f32::INFINITY)?;
        let t = hit.triangle as usize;
        let normal = self
            .mesh
            .interpolate(&self.mesh.normals, t, hit.barycentric)
            .normalize_or_zero();
        let uv = self.mesh.interpolate(&self.mesh.uvs, t, hit.barycentric);
        let frame = Frame::from_normal(normal);
        let wo = frame.to_local(-wi);
        let asset = &self.object.asset;
        let point = ShadingPoint {
            bsdf: self.object.finish.bsdf(),
            surface: PointSurface {
                albedo: asset.albedo.lookup(uv),
                roughness: asset.roughness.lookup(uv)[0],
            },
            frame,
            wo,
        };
        let visibility = asset.visibility.lookup(uv)[0];
        let origin = self.mesh.interpolate(&self.mesh.positions, t, hit.barycentric);
        let light = point.reflected(sampler, [rng.next_2d(), rng.next_2d()], |out| {
            if self.accel.occluded(origin, out, BOUNCE_RAY_OFFSET, f32::INFINITY) {
                [0.0; 3]
            } else {
                env.lookup(out)
            }
        });
        Some(light.map(|l| visibility * l))
    }
}

/// Offset along the ray of a bounce off the object, metres (self-hits).
const BOUNCE_RAY_OFFSET: f32 = 1e-4;
