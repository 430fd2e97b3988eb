//! The probe asset: a folder with `probe.json`, a mesh and its material textures (FORMATS.md).
//!
//! ```json
//! {"name": "soda_can", "mesh": "mesh.obj", "albedo": "albedo.exr",
//!  "roughness": "roughness.exr", "visibility": "visibility.exr"}
//! ```
//! Each texture is a path relative to the folder or a constant (`"albedo": [0.9, 0.9, 0.9]`,
//! `"roughness": 0.1`); `visibility` is optional and defaults to 1.

use std::path::Path;

use glam::Vec2;
use serde_json::{Map, Value};

use crate::error::{RenderError, Result};
use crate::image_io::RgbImage;
use crate::mesh::Mesh;

/// A texture indexed by OBJ uv, bilinear with clamp-to-edge; a constant is a 1x1 texture.
#[derive(Clone, Debug, PartialEq)]
pub struct Texture {
    /// The texels; row 0 is the top of the image, i.e. uv v = 1.
    pub image: RgbImage,
}

impl Texture {
    /// A texture with the same value everywhere.
    pub fn constant(value: [f32; 3]) -> Self {
        Self {
            image: RgbImage::filled(1, 1, value),
        }
    }

    /// Whether this is a constant (1x1) texture, written inline in `probe.json`.
    pub fn is_constant(&self) -> bool {
        self.image.width == 1 && self.image.height == 1
    }

    /// Bilinear lookup at OBJ texture coordinates, clamping at the edges.
    ///
    /// OBJ `vt` v = 0 is the BOTTOM row of the image, whereas image row 0 is the top: hence `1 - v`.
    pub fn lookup(&self, uv: Vec2) -> [f32; 3] {
        let (w, h) = (self.image.width, self.image.height);
        let x = (uv.x * w as f32 - 0.5).clamp(0.0, (w - 1) as f32);
        let y = ((1.0 - uv.y) * h as f32 - 0.5).clamp(0.0, (h - 1) as f32);
        let (col0, row0) = (x.floor() as usize, y.floor() as usize);
        let (fx, fy) = (x - col0 as f32, y - row0 as f32);
        let (col1, row1) = ((col0 + 1).min(w - 1), (row0 + 1).min(h - 1));
        let mut out = [0.0; 3];
        for (row, wy) in [(row0, 1.0 - fy), (row1, fy)] {
            for (col, wx) in [(col0, 1.0 - fx), (col1, fx)] {
                let t = self.image.get(row, col);
                for c in 0..3 {
                    out[c] += wx * wy * t[c];
                }
            }
        }
        out
    }
}

/// The material at one surface point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Material {
    /// Specular albedo A (Schlick's F0), linear RGB in [0, 1].
    pub albedo: [f32; 3],
    /// GGX roughness r in [0, 1]; alpha = r^2.
    pub roughness: f32,
    /// Soft visibility in [0, 1] multiplying the shaded radiance.
    pub visibility: f32,
}

/// A probe: its shape (mesh frame, metres) and spatially varying metallic material.
#[derive(Clone, Debug, PartialEq)]
pub struct ProbeAsset {
    /// The probe's name (e.g. `soda_can`).
    pub name: String,
    /// The triangle mesh, with uvs indexing the textures.
    pub mesh: Mesh,
    /// RGB specular albedo in [0, 1].
    pub albedo: Texture,
    /// Roughness r in [0, 1], in every channel.
    pub roughness: Texture,
    /// Soft visibility in [0, 1], in every channel (constant 1 when absent from `probe.json`).
    pub visibility: Texture,
}

/// How a texture field is read and checked.
struct TextureField {
    name: &'static str,
    /// Whether only the first channel counts (roughness, visibility) and is copied to all three.
    scalar: bool,
}

const ALBEDO: TextureField = TextureField {
    name: "albedo",
    scalar: false,
};
const ROUGHNESS: TextureField = TextureField {
    name: "roughness",
    scalar: true,
};
const VISIBILITY: TextureField = TextureField {
    name: "visibility",
    scalar: true,
};

impl TextureField {
    /// Reads the field's texture (file or constant) and checks that its values lie in [0, 1].
    fn read(&self, value: &Value, folder: &Path, json_path: &Path) -> Result<Texture> {
        let field_error = |rule: String| RenderError::field(json_path, self.name, rule);
        let (mut image, source) = match value {
            Value::String(file) => {
                let path = folder.join(file);
                (RgbImage::read_exr(&path).map_err(|e| e.with_field(self.name))?, path)
            }
            Value::Number(n) => {
                let v = n.as_f64().unwrap_or(f64::NAN) as f32;
                (RgbImage::filled(1, 1, [v; 3]), json_path.to_path_buf())
            }
            Value::Array(items) if items.len() == 3 && items.iter().all(Value::is_number) => {
                let rgb: [f32; 3] = std::array::from_fn(|c| items[c].as_f64().unwrap_or(f64::NAN) as f32);
                (RgbImage::filled(1, 1, rgb), json_path.to_path_buf())
            }
            other => {
                return Err(field_error(format!(
                    "{other} is neither a texture file path, a number nor [r, g, b]"
                )));
            }
        };
        if self.scalar {
            image.pixels.iter_mut().for_each(|p| *p = [p[0]; 3]);
        }
        let valid = |v: f32| (0.0..=1.0).contains(&v);
        let rule = if image.width * image.height == 1 {
            image.pixels[0]
                .iter()
                .find(|&&v| !valid(v))
                .map(|v| format!("value {v} outside [0, 1]"))
        } else {
            image.first_invalid(valid, "outside [0, 1]")
        };
        match rule {
            Some(rule) => Err(RenderError::field(source, self.name, rule)),
            None => Ok(Texture { image }),
        }
    }

    /// Writes the texture as `<name>.exr` in `folder` (or inline when constant) and returns its `probe.json` value.
    fn write(&self, texture: &Texture, folder: &Path) -> Result<Value> {
        let value = texture.image.pixels[0];
        Ok(match (texture.is_constant(), self.scalar) {
            (true, true) => Value::from(value[0]),
            (true, false) => Value::from(value.to_vec()),
            (false, _) => {
                let file = format!("{}.exr", self.name);
                texture.image.write_exr(folder.join(&file))?;
                Value::from(file)
            }
        })
    }
}

impl ProbeAsset {
    /// Reads a probe folder: `probe.json`, the mesh and the textures, checking every value range.
    pub fn read(folder: impl AsRef<Path>) -> Result<Self> {
        let folder = folder.as_ref();
        let json_path = folder.join("probe.json");
        let text = std::fs::read_to_string(&json_path).map_err(|e| RenderError::io(&json_path, "read", e))?;
        let json: Value = serde_json::from_str(&text).map_err(|e| RenderError::io(&json_path, "parse JSON", e))?;
        let Value::Object(fields) = json else {
            return Err(RenderError::file(&json_path, "top level must be a JSON object"));
        };
        if let Some(unknown) = fields
            .keys()
            .find(|k| !["name", "mesh", "albedo", "roughness", "visibility"].contains(&k.as_str()))
        {
            return Err(RenderError::field(&json_path, unknown.as_str(), "unknown field"));
        }
        let required = |name: &str| {
            fields
                .get(name)
                .ok_or_else(|| RenderError::field(&json_path, name, "missing (required)"))
        };
        let string = |name: &str| -> Result<String> {
            match required(name)? {
                Value::String(s) => Ok(s.clone()),
                other => Err(RenderError::field(&json_path, name, format!("{other} is not a string"))),
            }
        };
        let name = string("name")?;
        let mesh = Mesh::read_obj(folder.join(string("mesh")?))?;
        let albedo = ALBEDO.read(required(ALBEDO.name)?, folder, &json_path)?;
        let roughness = ROUGHNESS.read(required(ROUGHNESS.name)?, folder, &json_path)?;
        let visibility = match fields.get(VISIBILITY.name) {
            Some(value) => VISIBILITY.read(value, folder, &json_path)?,
            None => Texture::constant([1.0; 3]),
        };
        Ok(Self {
            name,
            mesh,
            albedo,
            roughness,
            visibility,
        })
    }

    /// Writes a probe folder: `probe.json`, `mesh.obj` (with vt and vn) and one EXR per non-constant texture.
    pub fn write(&self, folder: impl AsRef<Path>) -> Result<()> {
        let folder = folder.as_ref();
        std::fs::create_dir_all(folder).map_err(|e| RenderError::io(folder, "create folder", e))?;
        self.mesh.write_obj(folder.join("mesh.obj"))?;
        let mut json = Map::new();
        json.insert("name".into(), Value::from(self.name.clone()));
        json.insert("mesh".into(), Value::from("mesh.obj"));
        json.insert(ALBEDO.name.into(), ALBEDO.write(&self.albedo, folder)?);
        json.insert(ROUGHNESS.name.into(), ROUGHNESS.write(&self.roughness, folder)?);
        json.insert(VISIBILITY.name.into(), VISIBILITY.write(&self.visibility, folder)?);
        let json_path = folder.join("probe.json");
        let text = serde_json::to_string_pretty(&Value::Object(json))
            .map_err(|e| RenderError::io(&json_path, "serialise JSON", e))?;
        std::fs::write(&json_path, text + "\n").map_err(|e| RenderError::io(&json_path, "write", e))
    }

    /// The material at texture coordinates `uv`.
    pub fn material(&self, uv: Vec2) -> Material {
        Material {
            albedo: self.albedo.lookup(uv),
            roughness: self.roughness.lookup(uv)[0],
            visibility: self.visibility.lookup(uv)[0],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn texture_v_zero_is_the_bottom_row() {
        // 1 column, 2 rows: top row 0 (value 1), bottom row 1 (value 0).
        let texture = Texture {
            image: RgbImage::new(1, 2, vec![[1.0; 3], [0.0; 3]]),
        };
        assert_eq!(texture.lookup(Vec2::new(0.5, 0.0))[0], 0.0);
        assert_eq!(texture.lookup(Vec2::new(0.5, 1.0))[0], 1.0);
        assert_eq!(texture.lookup(Vec2::new(0.5, 0.5))[0], 0.5);
    }
}
