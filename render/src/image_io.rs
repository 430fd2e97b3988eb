//! Linear RGB float images (OpenEXR), probe masks (8-bit grayscale PNG) and tone-mapped previews.
//!
//! Photographs are linear HDR RGB OpenEXR (half or float, no gamma); a mask is an 8-bit grayscale
//! PNG of the same size where a value > 127 marks the probe (FORMATS.md, "Images and masks").

use std::path::Path;

use exr::prelude::{
    Encoding, FlatSamples, Image, Layer, LayerAttributes, ReadChannels, ReadLayers, SpecificChannels, WritableImage,
};

use crate::error::{RenderError, Result};

/// The most pixels an image read from a file may have (2^28: a 16384 x
/// 16384 map): a header that claims more is broken or hostile, and is
/// refused before anything is allocated for it.
pub const MAX_PIXELS: u64 = 1 << 28;

/// The most an OpenEXR file's pixels may expand over its length: deflate's
/// bound (1032:1) times PXR24's 4:3 (its floats stored in 3 bytes), with
/// room. No codec the reader knows expands more, so a header claiming more
/// pixel bytes than this allows is not the file's.
const MAX_EXR_EXPANSION: u64 = 2048;

/// The most bytes a decoder of PNG, JPEG or Radiance HDR may allocate:
/// `MAX_PIXELS` of 8-bit RGBA.
const MAX_DECODE_BYTES: u64 = 4 * MAX_PIXELS;

/// Fails on a `width x height` image of `path` with more than [`MAX_PIXELS`].
fn check_image_size(path: &Path, width: u64, height: u64) -> Result<()> {
    match width.checked_mul(height) {
        Some(pixels) if pixels <= MAX_PIXELS => Ok(()),
        _ => Err(RenderError::file(
            path,
            format!("its header claims {width}x{height} pixels, more than the {MAX_PIXELS} an image may have"),
        )),
    }
}

/// Reads the headers of OpenEXR file `path` and checks, before any pixel
/// is allocated, that they keep OpenEXR's rules, that each layer's size is within [`MAX_PIXELS`] and that
/// the file is long enough for it: its chunk offset table (8 bytes a
/// chunk) and its pixels (whole when uncompressed, at most
/// [`MAX_EXR_EXPANSION`] times the file's length when compressed).
fn check_exr_header(path: &Path) -> Result<()> {
    let length = std::fs::metadata(path)
        .map_err(|e| RenderError::io(path, "read OpenEXR", e))?
        .len();
    let meta = exr::meta::MetaData::read_from_file(path, false)
        .map_err(|e| RenderError::io(path, "read OpenEXR header", e))?;
    // The header's own rules first (a zero channel sampling divides by zero below).
    exr::meta::MetaData::validate(&meta.headers, false).map_err(|e| RenderError::io(path, "read OpenEXR header", e))?;
    for header in &meta.headers {
        let (width, height) = (header.layer_size.0 as u64, header.layer_size.1 as u64);
        check_image_size(path, width, height)?;
        let table = header.chunk_count as u64 * 8;
        let pixel_bytes = header.total_pixel_bytes() as u64;
        let room = match header.compression {
            exr::compression::Compression::Uncompressed => length,
            _ => length.saturating_mul(MAX_EXR_EXPANSION),
        };
        if table > length || pixel_bytes > room {
            return Err(RenderError::file(
                path,
                format!(
                    "its header claims {width}x{height} pixels ({pixel_bytes} bytes in {} chunks), \
                     more than the file's {length} bytes can hold (truncated or corrupt)",
                    header.chunk_count
                ),
            ));
        }
    }
    check_dwa_chunks(path, &meta.headers)
}

/// Checks the chunks of the DWAA / DWAB layers of OpenEXR file `path`:
/// each opens with eleven u64 counters (sizes, counts, the AC coder) that
/// the decoder allocates by unchecked, so each size must fit the chunk
/// and each count the block's pixels (a corrupt AC count once asked for
/// 146 GB). A chunk as long as its block's pixels is stored raw.
fn check_dwa_chunks(path: &Path, headers: &[exr::meta::header::Header]) -> Result<()> {
    use exr::block::chunk::CompressedBlock;
    use exr::compression::Compression;
    let is_dwa = |h: &exr::meta::header::Header| matches!(h.compression, Compression::DWAA(_) | Compression::DWAB(_));
    if !headers.iter().any(is_dwa) {
        return Ok(());
    }
    let corrupt = |e| RenderError::io(path, "read OpenEXR", e);
    let file = std::fs::File::open(path).map_err(|e| RenderError::io(path, "read OpenEXR", e))?;
    let chunks = exr::block::read(std::io::BufReader::new(file), false)
        .and_then(|reader| reader.all_chunks(false))
        .map_err(corrupt)?;
    for chunk in chunks {
        let chunk = chunk.map_err(corrupt)?;
        let Some(header) = headers.get(chunk.layer_index).filter(|h| is_dwa(h)) else {
            continue; // another codec's, or a layer the reader refuses itself
        };
        let bytes = match &chunk.compressed_block {
            CompressedBlock::ScanLine(block) => &block.compressed_pixels_le,
            CompressedBlock::Tile(block) => &block.compressed_pixels_le,
            _ => continue,
        };
        let block = header
            .get_block_data_indices(&chunk.compressed_block)
            .and_then(|tile| header.get_absolute_block_pixel_coordinates(tile))
            .map_err(corrupt)?;
        let raw = (block.size.area() * header.channels.bytes_per_pixel) as u64;
        if bytes.len() as u64 == raw {
            continue;
        }
        // Counters 1, 6-9 are uncompressed sizes and counts; 2-5, compressed sizes.
        for (index, counter) in bytes.chunks_exact(8).take(10).enumerate().skip(1) {
            let value = u64::from_le_bytes(counter.try_into().expect("8 bytes"));
            let limit = if (2..=5).contains(&index) {
                bytes.len() as u64
            } else {
                raw
            };
            if value > limit {
                return Err(RenderError::file(
                    path,
                    format!(
                        "a DWA-compressed chunk's counter {index} claims {value}, more than the {limit} \
                         its block can hold (truncated or corrupt)"
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// Opens an image of `path` (`what` it is, for errors) for decoding,
/// refusing a header larger than [`MAX_PIXELS`] or [`MAX_DECODE_BYTES`].
fn decode_within_limits(path: &Path, what: &str) -> Result<image::DynamicImage> {
    let open = |e| RenderError::io(path, &format!("open {what}"), e);
    let mut reader = image::ImageReader::open(path)
        .map_err(open)?
        .with_guessed_format()
        .map_err(open)?;
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(MAX_DECODE_BYTES);
    reader.limits(limits);
    let decode = |e| RenderError::io(path, &format!("decode {what}"), e);
    let decoder = reader.into_decoder().map_err(decode)?;
    let (width, height) = image::ImageDecoder::dimensions(&decoder);
    check_image_size(path, width as u64, height as u64)?;
    if image::ImageDecoder::total_bytes(&decoder) > MAX_DECODE_BYTES {
        return Err(RenderError::file(
            path,
            format!("its {width}x{height} pixels need more than the {MAX_DECODE_BYTES} bytes a decoder may take"),
        ));
    }
    image::DynamicImage::from_decoder(decoder).map_err(decode)
}

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
        check_exr_header(path)?;
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

    /// Reads a photo by its extension: OpenEXR (`.exr`) and Radiance
    /// (`.hdr`) as linear radiance; 8- or 16-bit PNG and JPEG (`.png`,
    /// `.jpg`, `.jpeg`) decoded from sRGB to linear in [0, 1] (alpha
    /// dropped). The [`PhotoEncoding`] says which, for a warning: an sRGB
    /// photo's exposure is unknown and its highlights clip at 1.
    pub fn read_photo(path: impl AsRef<Path>) -> Result<(Self, PhotoEncoding)> {
        let path = path.as_ref();
        let extension = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase())
            .unwrap_or_default();
        let decode = || decode_within_limits(path, "image");
        let (image, encoding) = match extension.as_str() {
            "exr" => return Ok((Self::read_exr(path)?, PhotoEncoding::Linear)),
            "hdr" => (Self::from_rgb32f(decode()?.into_rgb32f(), |v| v), PhotoEncoding::Linear),
            "png" | "jpg" | "jpeg" => {
                let decoded = decode()?;
                let bits = match decoded.color().bytes_per_pixel() / decoded.color().channel_count() {
                    1 => 8,
                    2 => 16,
                    _ => {
                        return Err(RenderError::file(
                            path,
                            format!(
                                "a {:?} image: PNG and JPEG photos must be 8 or 16 bits per channel",
                                decoded.color()
                            ),
                        ));
                    }
                };
                (
                    Self::from_rgb32f(decoded.into_rgb32f(), srgb_decode),
                    PhotoEncoding::Srgb { bits },
                )
            }
            other => {
                return Err(RenderError::file(
                    path,
                    format!("unsupported photo format `.{other}`: give OpenEXR (.exr), Radiance (.hdr), PNG or JPEG"),
                ));
            }
        };
        if image.width == 0 || image.height == 0 {
            return Err(RenderError::file(path, "image is empty"));
        }
        match image.first_invalid(|v| v.is_finite() && v >= 0.0, "is not a finite radiance >= 0") {
            Some(rule) => Err(RenderError::file(path, rule)),
            None => Ok((image, encoding)),
        }
    }

    /// The image as an 8-bit sRGB JPEG of `quality` (1 to 100), its radiance
    /// times `exposure` first (values past 1 clip at 255): what a camera
    /// that writes JPEGs keeps of a linear photo.
    pub fn encode_jpeg(&self, exposure: f32, quality: u8) -> Result<Vec<u8>> {
        let bytes: Vec<u8> = self
            .pixels
            .iter()
            .flat_map(|p| p.map(|v| (srgb_encode(v * exposure) * 255.0).round() as u8))
            .collect();
        let mut encoded = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut encoded, quality.clamp(1, 100))
            .encode(
                &bytes,
                self.width as u32,
                self.height as u32,
                image::ExtendedColorType::Rgb8,
            )
            .map_err(|e| RenderError::io(Path::new("<jpeg>"), "encode JPEG", e))?;
        Ok(encoded)
    }

    /// Decodes an 8-bit sRGB JPEG held in memory to linear values in [0, 1]
    /// (as [`read_photo`](Self::read_photo) reads a `.jpg` file).
    pub fn decode_jpeg(bytes: &[u8]) -> Result<Self> {
        let decoded = image::load_from_memory_with_format(bytes, image::ImageFormat::Jpeg)
            .map_err(|e| RenderError::io(Path::new("<jpeg>"), "decode JPEG", e))?;
        Ok(Self::from_rgb32f(decoded.into_rgb32f(), srgb_decode))
    }

    /// An RGB image from a decoded float buffer, each value through `map`.
    fn from_rgb32f(rgb: image::Rgb32FImage, map: impl Fn(f32) -> f32) -> Self {
        let (width, height) = (rgb.width() as usize, rgb.height() as usize);
        let pixels = rgb.pixels().map(|p| p.0.map(&map)).collect();
        Self::new(width, height, pixels)
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

/// The inverse sRGB transfer function (IEC 61966-2-1): an encoded value in [0, 1] to linear.
fn srgb_decode(encoded: f32) -> f32 {
    if encoded <= 0.040_45 {
        encoded / 12.92
    } else {
        ((encoded + 0.055) / 1.055).powf(2.4)
    }
}

/// How a photo's values relate to radiance ([`RgbImage::read_photo`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PhotoEncoding {
    /// Linear radiance (OpenEXR, Radiance HDR).
    Linear,
    /// Display-referred sRGB of this many bits, decoded to linear in [0, 1].
    Srgb {
        /// Bits per channel: 8 or 16.
        bits: u8,
    },
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

    /// Reads an 8-bit mask image (PNG, or any format the decoder knows): a
    /// grey value (the luma of a colour one) > 127 marks the probe, and
    /// where the image has alpha, a pixel must also be opaque (alpha > 127).
    pub fn read_png(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let decoded = decode_within_limits(path, "mask")?;
        if decoded.color().bytes_per_pixel() != decoded.color().channel_count() {
            return Err(RenderError::file(
                path,
                format!("a mask must have 8 bits per channel, found {:?}", decoded.color()),
            ));
        }
        let (width, height) = (decoded.width() as usize, decoded.height() as usize);
        let opaque: Vec<bool> = if decoded.color().has_alpha() {
            decoded.to_rgba8().pixels().map(|p| p.0[3] > 127).collect()
        } else {
            vec![true; width * height]
        };
        let luma = decoded.into_luma8().into_raw();
        Ok(Self::new(
            width,
            height,
            luma.into_iter().zip(opaque).map(|(v, o)| v > 127 && o).collect(),
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

    #[test]
    fn srgb_decoding_inverts_encoding() {
        for v in [0.0f32, 0.001, 0.0031308, 0.18, 0.5, 1.0] {
            assert!((srgb_decode(srgb_encode(v)) - v).abs() < 1e-6, "{v}");
        }
    }

    fn folder(name: &str) -> std::path::PathBuf {
        let dir = std::env::temp_dir().join(format!("render-image-io-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("temp dir");
        dir
    }

    /// An OpenEXR file with the i32s at `(offset, value)` past attribute
    /// `key`'s value size rewritten.
    fn exr_patched(dir: &Path, name: &str, key: &[u8], patches: &[(usize, i32)]) -> std::path::PathBuf {
        let path = dir.join(name);
        RgbImage::filled(4, 2, [0.5; 3]).write_exr(&path).expect("write");
        let mut bytes = std::fs::read(&path).expect("read");
        let value_at = bytes.windows(key.len()).position(|w| w == key).expect("the attribute") + key.len() + 4;
        for &(offset, value) in patches {
            let at = value_at + offset;
            bytes[at..at + 4].copy_from_slice(&value.to_le_bytes());
        }
        std::fs::write(&path, bytes).expect("write");
        path
    }

    /// A header that claims more pixels than an image may have, or than
    /// the file holds, or that breaks OpenEXR's rules, is an error naming
    /// the file, before any allocation (a claim of 2^40 pixels used to
    /// abort the program, a channel sampled every 0 pixels to panic).
    #[test]
    fn exr_headers_claiming_more_than_the_file_holds_are_errors() {
        let dir = folder("exr-claims");
        let window = b"dataWindow\0box2i\0";
        assert_eq!(
            RgbImage::read_exr(exr_patched(&dir, "same.exr", window, &[(8, 3)]))
                .expect("intact")
                .width,
            4
        );
        let (x_max, y_max) = (8, 12);
        // Each case: the file, the attribute, the (offset, value) patches, the rule named.
        let huge = [(x_max, 1 << 20), (y_max, 1 << 20)];
        let long = [(x_max, 4095), (y_max, 4095)];
        // The first channel's x sampling: past its name "B\0", type, linearity, reserved.
        let no_sampling = [(10, 0)];
        let cases = [
            (
                "huge.exr",
                &window[..],
                &huge[..],
                "more than the 268435456 an image may have",
            ),
            ("long.exr", &window[..], &long[..], "more than the file's"),
            ("sampling.exr", &b"channels\0chlist\0"[..], &no_sampling[..], "sampling"),
        ];
        for (name, key, patches, rule) in cases {
            let error = RgbImage::read_exr(exr_patched(&dir, name, key, patches))
                .expect_err(name)
                .to_string();
            assert!(error.contains(name) && error.contains(rule), "{error}");
        }
    }

    /// A DWAA chunk whose AC count is more than its block holds is an
    /// error naming the file (the decoder asked for 146 GB on one).
    #[test]
    fn dwa_chunks_claiming_more_than_their_block_are_errors() {
        let dir = folder("dwa");
        let path = dir.join("dwa.exr");
        let channels = SpecificChannels::rgb(|exr::math::Vec2(x, y): exr::math::Vec2<usize>| {
            let v = exr::prelude::f16::from_f32(0.1 + 0.01 * (x * y) as f32);
            (v, v, v)
        });
        let encoding = Encoding {
            compression: exr::compression::Compression::DWAA(None),
            blocks: exr::image::Blocks::ScanLines,
            line_order: exr::meta::attribute::LineOrder::Increasing,
        };
        let layer = Layer::new((32, 32), LayerAttributes::default(), encoding, channels);
        Image::from_layer(layer).write().to_file(&path).expect("write");
        assert_eq!(RgbImage::read_exr(&path).expect("intact").width, 32);
        // The offset table's first entry points just past the table: there the
        // first chunk's line (i32), size (i32), then its counters.
        let mut bytes = std::fs::read(&path).expect("read");
        let chunks = exr::meta::MetaData::read_from_file(&path, false)
            .expect("header")
            .headers[0]
            .chunk_count;
        let table = (0..bytes.len() - 8)
            .find(|&i| u64::from_le_bytes(bytes[i..i + 8].try_into().expect("8")) == (i + 8 * chunks) as u64)
            .expect("the offset table");
        let ac_count = table + 8 * chunks + 8 + 8 * 8;
        bytes[ac_count..ac_count + 8].copy_from_slice(&(1u64 << 36).to_le_bytes());
        std::fs::write(&path, bytes).expect("write");
        let error = RgbImage::read_exr(&path).expect_err("corrupt").to_string();
        assert!(error.contains("dwa.exr") && error.contains("counter 8"), "{error}");
    }

    /// Every format a photo may come in, read back as the radiance it encodes.
    #[test]
    fn photos_of_every_format_read_as_linear_radiance() {
        let dir = folder("photos");
        let (w, h) = (4u32, 3u32);
        // sRGB 188 is linear 0.5029; 16-bit 48316 the same level.
        let srgb8: Vec<u8> = (0..w * h * 3).map(|_| 188).collect();
        image::save_buffer(dir.join("a.png"), &srgb8, w, h, image::ExtendedColorType::Rgb8).expect("png");
        image::save_buffer(dir.join("a.jpg"), &srgb8, w, h, image::ExtendedColorType::Rgb8).expect("jpeg");
        let srgb16 =
            image::ImageBuffer::<image::Rgba<u16>, _>::from_pixel(w, h, image::Rgba([48316, 48316, 48316, 65535]));
        srgb16.save(dir.join("b.png")).expect("png16");
        // RGBE shares one exponent: channels within a factor of ten keep 1 %.
        let hdr = image::Rgb32FImage::from_pixel(w, h, image::Rgb([2.0, 4.0, 9.0]));
        image::DynamicImage::ImageRgb32F(hdr)
            .save(dir.join("c.hdr"))
            .expect("hdr");
        RgbImage::filled(w as usize, h as usize, [0.25, 4.0, 100.0])
            .write_exr(dir.join("d.exr"))
            .expect("exr");
        let cases = [
            ("a.png", [0.5029; 3], PhotoEncoding::Srgb { bits: 8 }, 1e-3),
            ("a.jpg", [0.5029; 3], PhotoEncoding::Srgb { bits: 8 }, 0.02),
            ("b.png", [0.5029; 3], PhotoEncoding::Srgb { bits: 16 }, 1e-3),
            ("c.hdr", [2.0, 4.0, 9.0], PhotoEncoding::Linear, 0.01),
            ("d.exr", [0.25, 4.0, 100.0], PhotoEncoding::Linear, 1e-6),
        ];
        for (name, expected, encoding, tolerance) in cases {
            let (image, found) = RgbImage::read_photo(dir.join(name)).expect(name);
            assert_eq!(
                (image.width, image.height, found),
                (w as usize, h as usize, encoding),
                "{name}"
            );
            for p in &image.pixels {
                for c in 0..3 {
                    assert!(
                        (p[c] / expected[c] - 1.0).abs() < tolerance,
                        "{name}: {p:?} vs {expected:?}"
                    );
                }
            }
        }
        std::fs::write(dir.join("e.tif"), b"II*\0").expect("tif");
        let error = RgbImage::read_photo(dir.join("e.tif")).expect_err("tif").to_string();
        assert!(error.contains("e.tif") && error.contains(".tif"), "{error}");
        std::fs::write(dir.join("f.png"), b"\x89PNG truncated").expect("broken");
        let error = RgbImage::read_photo(dir.join("f.png")).expect_err("broken").to_string();
        assert!(error.contains("f.png"), "{error}");
        // Every format cut short: an error naming the file, not a panic or a part image.
        for name in ["a.png", "a.jpg", "b.png", "c.hdr", "d.exr"] {
            let bytes = std::fs::read(dir.join(name)).expect(name);
            let cut = dir.join(format!("cut-{name}"));
            std::fs::write(&cut, &bytes[..bytes.len() / 2]).expect("cut");
            let error = RgbImage::read_photo(&cut).expect_err(name).to_string();
            assert!(error.contains(&format!("cut-{name}")), "{error}");
        }
        std::fs::remove_dir_all(&dir).expect("clean up");
    }

    /// A mask may be grey, colour or with alpha; 16 bits are refused.
    #[test]
    fn masks_of_any_8_bit_layout_are_read() {
        let dir = folder("masks");
        let (w, h) = (3u32, 1u32);
        image::save_buffer(dir.join("grey.png"), &[0, 200, 255], w, h, image::ExtendedColorType::L8).expect("grey");
        image::save_buffer(
            dir.join("rgb.png"),
            &[0, 0, 0, 200, 200, 200, 255, 255, 255],
            w,
            h,
            image::ExtendedColorType::Rgb8,
        )
        .expect("rgb");
        // White everywhere, the first pixel transparent.
        image::save_buffer(
            dir.join("rgba.png"),
            &[255, 255, 255, 0, 255, 255, 255, 255, 255, 255, 255, 255],
            w,
            h,
            image::ExtendedColorType::Rgba8,
        )
        .expect("rgba");
        for name in ["grey.png", "rgb.png", "rgba.png"] {
            let mask = Mask::read_png(dir.join(name)).expect(name);
            assert_eq!(mask.inside, vec![false, true, true], "{name}");
        }
        image::save_buffer(dir.join("deep.png"), &[0u8; 6], w, h, image::ExtendedColorType::L16).expect("16-bit");
        let error = Mask::read_png(dir.join("deep.png")).expect_err("16-bit").to_string();
        assert!(error.contains("deep.png") && error.contains("8 bits"), "{error}");
        std::fs::remove_dir_all(&dir).expect("clean up");
    }
}
