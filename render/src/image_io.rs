//! Linear RGB float images (OpenEXR), probe masks (8-bit grayscale PNG) and tone-mapped previews.
//!
//! Photographs are linear HDR RGB OpenEXR (half or float, no gamma); a mask is an 8-bit grayscale
//! PNG of the same size where a value > 127 marks the probe (FORMATS.md, "Images and masks").

use std::path::Path;

use exr::prelude::{
    Encoding, FlatSamples, Image, Layer, LayerAttributes, ReadChannels, ReadLayers, SpecificChannels, WritableImage,
};

use crate::error::{RenderError, Result};

/// A linear RGB float image, row-major with row 0 at the top.
#[derive(Clone, Debug, PartialEq)]
pub struct RgbImage {
    /// Number of columns.
    pub width: usize,
    /// Number of rows.
    pub height: usize,
    /// `width * height` RGB values, row-major.
    pub pixels: Vec<[f32; 3]>,
}

impl RgbImage {
    /// An image from its pixels; panics when `pixels.len() != width * height` (a programming error).
    pub fn new(width: usize, height: usize, pixels: Vec<[f32; 3]>) -> Self {
        assert_eq!(
            pixels.len(),
            width * height,
            "RgbImage::new: {} pixels for a {width}x{height} image",
            pixels.len()
        );
        Self { width, height, pixels }
    }

    /// An image where every pixel holds `value`.
    pub fn filled(width: usize, height: usize, value: [f32; 3]) -> Self {
        Self::new(width, height, vec![value; width * height])
    }

    /// The pixel at (row, col).
    pub fn get(&self, row: usize, col: usize) -> [f32; 3] {
        self.pixels[row * self.width + col]
    }

    /// Reads the first layer of an OpenEXR file (half, float or uint channels) as RGB.
    ///
    /// Channels are found by name (`R`, `G`, `B`, also with a layer prefix such as `diffuse.R`); a file
    /// with a single channel (e.g. `Y`) is read as grey. Non-finite values are rejected.
    pub fn read_exr(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let image = exr::prelude::read()
            .no_deep_data()
            .largest_resolution_level()
            .all_channels()
            .first_valid_layer()
            .all_attributes()
            .from_file(path)
            .map_err(|e| RenderError::io(path, "read OpenEXR", e))?;
        let layer = image.layer_data;
        let (width, height) = (layer.size.0, layer.size.1);
        if width == 0 || height == 0 {
            return Err(RenderError::file(path, format!("image is empty ({width}x{height})")));
        }
        let channels = &layer.channel_data.list;
        let find = |name: &str| {
            channels.iter().find(|c| {
                let full = c.name.to_string();
                full == name || full.ends_with(&format!(".{name}"))
            })
        };
        let rgb: [&FlatSamples; 3] = match (find("R"), find("G"), find("B")) {
            (Some(r), Some(g), Some(b)) => [&r.sample_data, &g.sample_data, &b.sample_data],
            _ if channels.len() == 1 => [&channels[0].sample_data; 3],
            _ => {
                let names: Vec<String> = channels.iter().map(|c| c.name.to_string()).collect();
                return Err(RenderError::file(
                    path,
                    format!(
                        "missing channels: need R, G and B (or a single channel), found [{}]",
                        names.join(", ")
                    ),
                ));
            }
        };
        let [r, g, b] = rgb.map(|samples| samples.values_as_f32().collect::<Vec<f32>>());
        let pixels: Vec<[f32; 3]> = (0..width * height).map(|i| [r[i], g[i], b[i]]).collect();
        let image = Self::new(width, height, pixels);
        match image.first_invalid(f32::is_finite, "is not finite") {
            Some(rule) => Err(RenderError::file(path, rule)),
            None => Ok(image),
        }
    }

    /// Describes the first value for which `valid` is false ("texel (row r, col c) channel G = -1 `rule`"), if any.
    pub(crate) fn first_invalid(&self, valid: impl Fn(f32) -> bool, rule: &str) -> Option<String> {
        let i = self.pixels.iter().position(|p| !p.iter().all(|&v| valid(v)))?;
        let pixel = self.pixels[i];
        let c = pixel.iter().position(|&v| !valid(v))?;
        let (row, col) = (i / self.width, i % self.width);
        let channel = ["R", "G", "B"][c];
        Some(format!(
            "texel (row {row}, col {col}) channel {channel} = {} {rule}",
            pixel[c]
        ))
    }

    /// Writes a float RGB OpenEXR file with lossless ZIP compression (CRATES.md).
    pub fn write_exr(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        let channels = SpecificChannels::rgb(|exr::math::Vec2(x, y): exr::math::Vec2<usize>| {
            let [r, g, b] = self.pixels[y * self.width + x];
            (r, g, b)
        });
        let layer = Layer::new(
            (self.width, self.height),
            LayerAttributes::default(),
            Encoding::SMALL_LOSSLESS,
            channels,
        );
        Image::from_layer(layer)
            .write()
            .to_file(path)
            .map_err(|e| RenderError::io(path, "write OpenEXR", e))
    }

    /// Writes an 8-bit sRGB PNG for looking at: radiance x 2^`exposure_stops`, clamped to [0, 1], sRGB-encoded.
    pub fn write_png_preview(&self, path: impl AsRef<Path>, exposure_stops: f32) -> Result<()> {
        let path = path.as_ref();
        let scale = exposure_stops.exp2();
        let bytes: Vec<u8> = self
            .pixels
            .iter()
            .flat_map(|p| p.map(|v| (srgb_encode(v * scale) * 255.0).round() as u8))
            .collect();
        image::save_buffer(
            path,
            &bytes,
            self.width as u32,
            self.height as u32,
            image::ExtendedColorType::Rgb8,
        )
        .map_err(|e| RenderError::io(path, "write PNG", e))
    }
}

/// The sRGB transfer function (IEC 61966-2-1) of a linear value clamped to [0, 1]; NaN maps to 0.
fn srgb_encode(linear: f32) -> f32 {
    let x = if linear.is_nan() { 0.0 } else { linear.clamp(0.0, 1.0) };
    if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

/// A binary probe mask: `true` where the probe is.
#[derive(Clone, Debug, PartialEq)]
pub struct Mask {
    /// Number of columns.
    pub width: usize,
    /// Number of rows.
    pub height: usize,
    /// `width * height` flags, row-major, row 0 at the top.
    pub inside: Vec<bool>,
}

impl Mask {
    /// A mask from its flags; panics when `inside.len() != width * height` (a programming error).
    pub fn new(width: usize, height: usize, inside: Vec<bool>) -> Self {
        assert_eq!(
            inside.len(),
            width * height,
            "Mask::new: {} flags for a {width}x{height} mask",
            inside.len()
        );
        Self { width, height, inside }
    }

    /// Reads an 8-bit grayscale PNG; a value > 127 marks the probe.
    pub fn read_png(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let decoded = image::ImageReader::open(path)
            .map_err(|e| RenderError::io(path, "open PNG", e))?
            .with_guessed_format()
            .map_err(|e| RenderError::io(path, "open PNG", e))?
            .decode()
            .map_err(|e| RenderError::io(path, "decode PNG", e))?;
        let image::DynamicImage::ImageLuma8(gray) = decoded else {
            return Err(RenderError::file(
                path,
                format!("mask must be an 8-bit grayscale PNG, found {:?}", decoded.color()),
            ));
        };
        let (width, height) = (gray.width() as usize, gray.height() as usize);
        Ok(Self::new(
            width,
            height,
            gray.into_raw().into_iter().map(|v| v > 127).collect(),
        ))
    }

    /// Writes an 8-bit grayscale PNG: 255 inside, 0 outside.
    pub fn write_png(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        let bytes: Vec<u8> = self.inside.iter().map(|&m| if m { 255 } else { 0 }).collect();
        image::save_buffer(
            path,
            &bytes,
            self.width as u32,
            self.height as u32,
            image::ExtendedColorType::L8,
        )
        .map_err(|e| RenderError::io(path, "write PNG", e))
    }

    /// Number of pixels inside the mask.
    pub fn count(&self) -> usize {
        self.inside.iter().filter(|&&m| m).count()
    }
}

/// Reads a photograph and its mask and checks that they have the same size.
pub fn read_image_and_mask(image_path: impl AsRef<Path>, mask_path: impl AsRef<Path>) -> Result<(RgbImage, Mask)> {
    let (image_path, mask_path) = (image_path.as_ref(), mask_path.as_ref());
    let image = RgbImage::read_exr(image_path)?;
    let mask = Mask::read_png(mask_path)?;
    if (image.width, image.height) != (mask.width, mask.height) {
        return Err(RenderError::file(
            mask_path,
            format!(
                "mask size {}x{} differs from image {} size {}x{}",
                mask.width,
                mask.height,
                image_path.display(),
                image.width,
                image.height
            ),
        ));
    }
    Ok((image, mask))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_encoding_matches_reference_values() {
        assert_eq!(srgb_encode(0.0), 0.0);
        assert!((srgb_encode(1.0) - 1.0).abs() < 1e-6);
        assert_eq!(srgb_encode(7.0), srgb_encode(1.0));
        assert!((srgb_encode(0.18) - 0.461_356).abs() < 1e-5);
    }
}
