//! Images on a tape and their bilinear lookups: the environment map (by
//! direction, FORMATS.md's lat-long mapping) and the probe's material
//! textures (by OBJ uv). Differentiable in the texels (the gathers scatter
//! their adjoints back) and in the lookup position (through the bilinear
//! weights).

use autodiff::{Real, Tape, Var, Vec3 as Vec3Var};
use glam::Vec2;

use crate::envmap::EnvMap;
use crate::image_io::RgbImage;
use crate::probe::Texture;
use crate::sampling::EnvSampler;

/// An RGB image on a tape: texel-major RGB (`(row * width + col) * 3 + channel`).
#[derive(Clone, Copy, Debug)]
pub struct ImageVars<'t, T: Real> {
    /// The texels (a leaf when gradients are wanted).
    pub texels: Var<'t, T>,
    /// Columns.
    pub width: usize,
    /// Rows (row 0 at the top).
    pub height: usize,
}

/// Texel-major RGB values of an image.
pub fn image_texels<T: Real>(image: &RgbImage) -> Vec<T> {
    image.pixels.iter().flat_map(|p| p.map(|c| T::c(c as f64))).collect()
}

impl<'t, T: Real> ImageVars<'t, T> {
    /// Records an image: a leaf (`differentiable`) or a constant.
    pub fn new(tape: &'t Tape<T>, image: &RgbImage, differentiable: bool) -> Self {
        let texels = image_texels::<T>(image);
        let texels = if differentiable {
            tape.leaf(&texels)
        } else {
            tape.constant(&texels)
        };
        ImageVars {
            texels,
            width: image.width,
            height: image.height,
        }
    }

    /// Records an environment map.
    pub fn env(tape: &'t Tape<T>, env: &EnvMap, differentiable: bool) -> Self {
        Self::new(tape, &env.to_image(), differentiable)
    }

    /// Wraps texels already on a tape.
    pub fn from_texels(texels: Var<'t, T>, width: usize, height: usize) -> Self {
        assert_eq!(
            texels.len(),
            width * height * 3,
            "ImageVars: {width}x{height} RGB needs {} values",
            width * height * 3
        );
        ImageVars { texels, width, height }
    }

    /// Bilinear lookup at continuous texel coordinates (`x` = column, `y` =
    /// row, texel centres at integers), wrapping columns when `wrap_columns`
    /// and clamping otherwise; rows always clamp.
    pub fn bilinear(&self, x: Var<'t, T>, y: Var<'t, T>, wrap_columns: bool) -> [Var<'t, T>; 3] {
        let taps = bilinear_taps(x, y, self.width, self.height, wrap_columns);
        std::array::from_fn(|c| {
            let g = |(t, w): (Var<'t, T>, Var<'t, T>)| self.texels.gather_channel(t, 3, c) * w;
            g(taps[0]) + g(taps[1]) + g(taps[2]) + g(taps[3])
        })
    }

    /// The environment map's radiance arriving from unit directions `d`
    /// (pointing from the scene to the light).
    pub fn env_radiance(&self, d: Vec3Var<'t, T>) -> [Var<'t, T>; 3] {
        let (x, y) = env_texel_coordinates(d, self.width, self.height);
        self.bilinear(x, y, true)
    }
}

/// The four texels around continuous texel coordinates (`x` = column, `y` =
/// row, texel centres at integers) of a `width` x `height` image and their
/// bilinear weights: (texel index, weight), columns wrapping when
/// `wrap_columns` and clamping otherwise, rows clamping.
fn bilinear_taps<'t, T: Real>(
    x: Var<'t, T>,
    y: Var<'t, T>,
    width: usize,
    height: usize,
    wrap_columns: bool,
) -> [(Var<'t, T>, Var<'t, T>); 4] {
    let (w, h) = (T::c(width as f64), T::c(height as f64));
    let x = if wrap_columns {
        x
    } else {
        x.clamp(T::zero(), w - T::one())
    };
    let x0 = x.floor();
    let y0 = y.floor();
    let fx = x - x0;
    let fy = (y - y0).clamp(T::zero(), T::one());
    let column = |c: Var<'t, T>| {
        if wrap_columns {
            // c mod width, for c >= -width.
            c - (c * (T::one() / w)).floor() * w
        } else {
            c.min_scalar(w - T::one())
        }
    };
    let (c0, c1) = (column(x0), column(x0 + T::one()));
    let (r0, r1) = (
        y0.clamp(T::zero(), h - T::one()),
        (y0 + T::one()).clamp(T::zero(), h - T::one()),
    );
    let width = x.tape().scalar(w);
    let (gx, gy) = (fx.rsub(T::one()), fy.rsub(T::one()));
    [
        (r0.mul_add(width, c0), gx * gy),
        (r0.mul_add(width, c1), fx * gy),
        (r1.mul_add(width, c0), gx * fy),
        (r1.mul_add(width, c1), fx * fy),
    ]
}

/// Continuous texel coordinates (column, row; texel centres at integers) of
/// unit directions `d` in a `width` x `height` lat-long map:
/// `u = atan2(x, -z) / 2pi` wrapped into [0, 1), `v = acos(y) / pi`, texel
/// centres at +0.5 (FORMATS.md).
fn env_texel_coordinates<'t, T: Real>(d: Vec3Var<'t, T>, width: usize, height: usize) -> (Var<'t, T>, Var<'t, T>) {
    let u = d.x.atan2(-d.z) * T::c(0.5 / std::f64::consts::PI);
    let u = u.lt(d.x.tape().scalar(T::zero())).select(u + T::one(), u);
    // Clamped off the poles, where acos' derivative is infinite.
    let v = d.y.clamp(T::c(-1.0 + 1e-7), T::c(1.0 - 1e-7)).acos() * T::c(1.0 / std::f64::consts::PI);
    (u * T::c(width as f64) - T::c(0.5), v * T::c(height as f64) - T::c(0.5))
}

/// The solid-angle pdf of an [`EnvSampler`] on a tape, at any direction:
/// the bilinear lookup of its density in (u, v), as the radiance is looked
/// up, over the lat-long Jacobian `2 pi^2 sin(theta)`. Continuous in the
/// direction (why that matters: `sampling::env`); a constant of the tape.
#[derive(Clone, Copy, Debug)]
pub struct EnvPdfVars<'t, T: Real> {
    /// `p(u, v)` at the texel centres, row-major.
    density: Var<'t, T>,
    width: usize,
    height: usize,
}

impl<'t, T: Real> EnvPdfVars<'t, T> {
    /// Records the density of `sampler`.
    pub fn new(tape: &'t Tape<T>, sampler: &EnvSampler) -> Self {
        let map = sampler.density_map();
        let density: Vec<T> = map.radiance().iter().map(|t| T::c(t[0] as f64)).collect();
        EnvPdfVars {
            density: tape.constant(&density),
            width: map.width(),
            height: map.height(),
        }
    }

    /// The pdf of unit directions `d` (world, towards the light).
    pub fn pdf(&self, d: Vec3Var<'t, T>) -> Var<'t, T> {
        let (x, y) = env_texel_coordinates(d, self.width, self.height);
        let taps = bilinear_taps(x, y, self.width, self.height, true);
        let g = |(t, w): (Var<'t, T>, Var<'t, T>)| self.density.gather(t) * w;
        let pdf_uv = g(taps[0]) + g(taps[1]) + g(taps[2]) + g(taps[3]);
        // sqrt(x^2 + z^2) keeps its precision near the poles; kept off 0 there (pdf_uv is finite).
        let sin_theta = d.x.mul_add(d.x, d.z * d.z).max_scalar(T::c(1e-14)).sqrt();
        pdf_uv / (sin_theta * T::c(2.0 * std::f64::consts::PI * std::f64::consts::PI))
    }
}

/// A probe texture on a tape: a constant (1x1) texture stays a scalar per
/// channel (no lookup); an image is looked up bilinearly by uv.
#[derive(Clone, Copy, Debug)]
pub enum TextureVars<'t, T: Real> {
    /// One value per channel everywhere.
    Constant([Var<'t, T>; 3]),
    /// A texture image.
    Image(ImageVars<'t, T>),
}

impl<'t, T: Real> TextureVars<'t, T> {
    /// Records a texture: leaves (`differentiable`) or constants.
    pub fn new(tape: &'t Tape<T>, texture: &Texture, differentiable: bool) -> Self {
        if texture.is_constant() {
            let v = texture.image.pixels[0];
            let record = |c: f32| {
                let c = [T::c(c as f64)];
                if differentiable {
                    tape.leaf(&c)
                } else {
                    tape.constant(&c)
                }
            };
            TextureVars::Constant([record(v[0]), record(v[1]), record(v[2])])
        } else {
            TextureVars::Image(ImageVars::new(tape, &texture.image, differentiable))
        }
    }

    /// The values at OBJ texture coordinates (v = 0 is the image's bottom
    /// row, hence 1 - v), clamping at the edges.
    pub fn lookup(&self, u: Var<'t, T>, v: Var<'t, T>) -> [Var<'t, T>; 3] {
        match self {
            TextureVars::Constant(c) => *c,
            TextureVars::Image(image) => {
                let x = u * T::c(image.width as f64) - T::c(0.5);
                let y = v.rsub(T::one()) * T::c(image.height as f64) - T::c(0.5);
                image.bilinear(x, y, false)
            }
        }
    }

    /// The arrays that hold the texture's values (for gradients).
    pub fn vars(&self) -> Vec<Var<'t, T>> {
        match self {
            TextureVars::Constant(c) => c.to_vec(),
            TextureVars::Image(image) => vec![image.texels],
        }
    }
}

/// The four texels and weights of an env map's bilinear lookup at map
/// coordinates `uv` (FORMATS.md: texel centres at +0.5, wrap in u, clamp in
/// v), without a tape: what [`ImageVars::env_radiance`] reads, for the light
/// transport.
#[inline]
pub fn env_taps(uv: Vec2, width: usize, height: usize) -> ([u32; 4], [f32; 4]) {
    let x = uv.x * width as f32 - 0.5;
    let y = (uv.y * height as f32 - 0.5).clamp(0.0, (height - 1) as f32);
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let c0 = (x0 as i64).rem_euclid(width as i64) as usize;
    let c1 = (c0 + 1) % width;
    let r0 = y0 as usize;
    let r1 = (r0 + 1).min(height - 1);
    let t = |r: usize, c: usize| (r * width + c) as u32;
    (
        [t(r0, c0), t(r0, c1), t(r1, c0), t(r1, c1)],
        [(1.0 - fx) * (1.0 - fy), fx * (1.0 - fy), (1.0 - fx) * fy, fx * fy],
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::envmap::{EnvMap, uv_to_direction};
    use autodiff::gradcheck::{Input, gradcheck, uniform};
    use glam::Vec2;

    fn small_env() -> EnvMap {
        let (w, h) = (16, 8);
        let texels = (0..w * h)
            .map(|i| [i as f32 * 0.1, 1.0 + (i % 7) as f32, (i % 3) as f32 * 0.5])
            .collect();
        EnvMap::new(w, h, texels).expect("a valid env map")
    }

    #[test]
    fn env_radiance_matches_the_scalar_lookup_everywhere_including_seam_and_poles() {
        let env = small_env();
        let tape = Tape::<f64>::new();
        let image = ImageVars::env(&tape, &env, false);
        let mut dirs = Vec::new();
        for i in 0..40 {
            for j in 0..20 {
                dirs.push(uv_to_direction(Vec2::new(
                    (i as f32 + 0.13) / 40.0,
                    (j as f32 + 0.37) / 20.0,
                )));
            }
        }
        // The seam, and next to the poles (at a pole u is undefined and the
        // sign of a zero decides it).
        dirs.extend([
            glam::Vec3::new(0.0, 0.0, -1.0),
            glam::Vec3::new(1e-4, 0.0, -1.0).normalize(),
            glam::Vec3::new(1e-3, 1.0, 2e-3).normalize(),
            glam::Vec3::new(-2e-3, -1.0, 1e-3).normalize(),
        ]);
        let c = |f: fn(&glam::Vec3) -> f32| tape.constant(&dirs.iter().map(|d| f(d) as f64).collect::<Vec<_>>());
        let d = Vec3Var::new(c(|d| d.x), c(|d| d.y), c(|d| d.z));
        let rgb = image.env_radiance(d);
        let got: Vec<Vec<f64>> = rgb.iter().map(|v| tape.to_vec(*v)).collect();
        for (k, dir) in dirs.iter().enumerate() {
            let want = env.lookup(*dir);
            for ch in 0..3 {
                assert!(
                    (got[ch][k] - want[ch] as f64).abs() < 1e-4 * (1.0 + want[ch].abs() as f64),
                    "{dir}: channel {ch}: {} vs {}",
                    got[ch][k],
                    want[ch]
                );
            }
        }
    }

    #[test]
    fn env_radiance_is_differentiable_in_texels_and_direction() {
        let env = small_env();
        let texels = image_texels::<f64>(&env.to_image());
        let n = 12;
        let inputs = [
            Input::Var(texels),
            Input::Var(uniform(n, -1.0, 1.0, 1)),
            Input::Var(uniform(n, -0.9, 0.9, 2)),
            Input::Var(uniform(n, -1.0, 1.0, 3)),
        ];
        let report = gradcheck(&inputs, |_, v| {
            let image = ImageVars::from_texels(v[0], 16, 8);
            let d = Vec3Var::new(v[1], v[2], v[3]).normalize(1e-9);
            let [r, g, b] = image.env_radiance(d);
            r + g * 2.0 + b * 3.0
        });
        assert!(report.worst_rel_error < 1e-6, "{report}");
    }

    #[test]
    fn env_pdf_on_a_tape_is_the_samplers_pdf_and_is_differentiable() {
        let env = small_env();
        let sampler = EnvSampler::new(&env);
        let tape = Tape::<f64>::new();
        let pdf = EnvPdfVars::new(&tape, &sampler);
        let mut dirs: Vec<glam::Vec3> = (0..400)
            .map(|k| {
                uv_to_direction(Vec2::new(
                    (k % 40) as f32 / 40.0 + 0.011,
                    (k / 40) as f32 / 10.0 + 0.023,
                ))
            })
            .collect();
        // The seam, and next to the poles.
        dirs.extend([
            glam::Vec3::new(1e-4, 0.0, -1.0).normalize(),
            glam::Vec3::new(-1e-4, 0.0, -1.0).normalize(),
            glam::Vec3::new(1e-3, 1.0, 2e-3).normalize(),
            glam::Vec3::new(-2e-3, -1.0, 1e-3).normalize(),
        ]);
        let c = |f: fn(&glam::Vec3) -> f32| tape.constant(&dirs.iter().map(|d| f(d) as f64).collect::<Vec<_>>());
        let got = tape.to_vec(pdf.pdf(Vec3Var::new(c(|d| d.x), c(|d| d.y), c(|d| d.z))));
        for (d, got) in dirs.iter().zip(got) {
            let want = sampler.pdf(*d) as f64;
            assert!((got - want).abs() < 1e-4 * want, "{d}: {got} vs {want}");
        }
        let n = 12;
        let inputs = [
            Input::Var(uniform(n, -1.0, 1.0, 1)),
            Input::Var(uniform(n, -0.9, 0.9, 2)),
            Input::Var(uniform(n, -1.0, 1.0, 3)),
        ];
        let report = gradcheck(&inputs, |t, v| {
            EnvPdfVars::new(t, &sampler).pdf(Vec3Var::new(v[0], v[1], v[2]).normalize(1e-9))
        });
        assert!(report.worst_rel_error < 1e-6, "{report}");
    }

    #[test]
    fn texture_lookup_matches_the_scalar_lookup_and_is_differentiable() {
        let image = RgbImage {
            width: 5,
            height: 4,
            pixels: (0..20).map(|i| [i as f32, (i * i) as f32 * 0.1, 1.0]).collect(),
        };
        let texture = Texture { image: image.clone() };
        let tape = Tape::<f64>::new();
        let vars = TextureVars::new(&tape, &texture, false);
        let uvs: Vec<Vec2> = (0..30)
            .map(|k| Vec2::new((k % 6) as f32 / 5.0 * 1.2 - 0.1, (k / 6) as f32 / 4.0))
            .collect();
        let u = tape.constant(&uvs.iter().map(|p| p.x as f64).collect::<Vec<_>>());
        let v = tape.constant(&uvs.iter().map(|p| p.y as f64).collect::<Vec<_>>());
        let rgb = vars.lookup(u, v);
        for (k, uv) in uvs.iter().enumerate() {
            let want = texture.lookup(*uv);
            for ch in 0..3 {
                let got = tape.value(rgb[ch])[k];
                assert!(
                    (got - want[ch] as f64).abs() < 1e-4,
                    "uv {uv} channel {ch}: {got} vs {}",
                    want[ch]
                );
            }
        }
        let inputs = [
            Input::Var(image_texels(&image)),
            Input::Var(uniform(8, 0.05, 0.95, 4)),
            Input::Var(uniform(8, 0.05, 0.95, 5)),
        ];
        let report = gradcheck(&inputs, |_, v| {
            let t = TextureVars::Image(ImageVars::from_texels(v[0], 5, 4));
            let [r, g, b] = t.lookup(v[1], v[2]);
            r * g + b
        });
        assert!(report.worst_rel_error < 1e-6, "{report}");
    }

    #[test]
    fn env_taps_reproduce_the_map_s_lookup() {
        let (w, h) = (16, 8);
        let texels: Vec<[f32; 3]> = (0..w * h).map(|i| [i as f32, (i % 5) as f32, 1.0]).collect();
        let env = EnvMap::new(w, h, texels.clone()).expect("env");
        for k in 0..200 {
            let d = uv_to_direction(glam::Vec2::new((k as f32 * 0.37).fract(), (k as f32 * 0.61).fract()));
            let (t, wt) = env_taps(crate::envmap::direction_to_uv(d), w, h);
            let got: f32 = t.iter().zip(&wt).map(|(&t, &wt)| texels[t as usize][0] * wt).sum();
            assert!(
                (got - env.lookup(d)[0]).abs() < 1e-3,
                "{d}: {got} vs {}",
                env.lookup(d)[0]
            );
        }
    }
}
