//! The objective as a JSON file (format: [`Objective::from_json_str`]).
//!
//! Every error names the line (and column) it is about. Each term is parsed
//! from its own raw text, whose place in the file gives the line of errors
//! found after parsing (a field that does not apply to the term).

use std::fmt;
use std::path::Path;

use serde::Deserialize;
use serde::de::{self, Deserializer, MapAccess, Visitor};
use serde_json::value::RawValue;

use render::RenderError;

use crate::error::Result;

use super::{
    Barycenter, Chamfer, DecayShape, LatitudePrior, LeastSquaresData, LightSmoothness, MaskL1, NeighbourSmoothness,
    Objective, OrientationPrior, Phase, Phases, RgbL1, RgbVariant, Weight, WeightedTerm, Weighting,
};

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileSpec<'a> {
    #[serde(borrow)]
    terms: Vec<&'a RawValue>,
}

/// The term kinds a file can name.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum TermKind {
    RgbL1,
    MaskL1,
    Chamfer,
    Barycenter,
    Orientation,
    LightSmoothness,
    DataLeastSquares,
    NeighbourSmoothness,
    LatitudePrior,
}

impl TermKind {
    const ALL: [(TermKind, &'static str); 9] = [
        (TermKind::RgbL1, "rgb_l1"),
        (TermKind::MaskL1, "mask_l1"),
        (TermKind::Chamfer, "chamfer"),
        (TermKind::Barycenter, "barycenter"),
        (TermKind::Orientation, "orientation"),
        (TermKind::LightSmoothness, "light_smoothness"),
        (TermKind::DataLeastSquares, "data_least_squares"),
        (TermKind::NeighbourSmoothness, "neighbour_smoothness"),
        (TermKind::LatitudePrior, "latitude_prior"),
    ];

    fn name(self) -> &'static str {
        Self::ALL
            .iter()
            .find(|(k, _)| *k == self)
            .map(|(_, n)| *n)
            .expect("every kind is listed")
    }
}

impl<'de> Deserialize<'de> for TermKind {
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        let name = String::deserialize(d)?;
        TermKind::ALL
            .iter()
            .find(|(_, n)| *n == name)
            .map(|(k, _)| *k)
            .ok_or_else(|| {
                let names: Vec<&str> = TermKind::ALL.iter().map(|(_, n)| *n).collect();
                de::Error::custom(format!("unknown term `{name}`: the terms are {}", names.join(", ")))
            })
    }
}

/// The fields of one term; which apply depends on `term`.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct TermSpec {
    term: TermKind,
    weight: Option<Weight>,
    variant: Option<RgbVariant>,
    sigma_deg: Option<f64>,
    directions: Option<usize>,
    edge: Option<f64>,
    chroma: Option<f64>,
    phases: Option<Vec<Phase>>,
}

impl<'de> Deserialize<'de> for Phase {
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        let name = String::deserialize(d)?;
        Phase::ALL
            .into_iter()
            .find(|p| p.name() == name)
            .ok_or_else(|| de::Error::custom(format!("unknown phase `{name}`: the phases are pose, lighting")))
    }
}

/// A weight is a number, or `{"decay_to_zero": initial, "until": fraction,
/// "shape": "linear" | "cosine"}`; it is validated where it is read, so the
/// error points at it.
impl<'de> Deserialize<'de> for Weight {
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        d.deserialize_any(WeightVisitor)
    }
}

struct WeightVisitor;

const DECAY_FIELDS: &[&str] = &["decay_to_zero", "until", "shape"];

impl WeightVisitor {
    fn checked<E: de::Error>(w: Weight) -> std::result::Result<Weight, E> {
        w.validate()
            .map(|()| w)
            .map_err(|e| E::custom(format!("{} {}", e.field_name().unwrap_or("weight"), e.rule())))
    }
}

impl<'de> Visitor<'de> for WeightVisitor {
    type Value = Weight;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str(r#"a number, or {"decay_to_zero": initial, "until": fraction of the run}"#)
    }

    fn visit_f64<E: de::Error>(self, v: f64) -> std::result::Result<Weight, E> {
        Self::checked(Weight::Constant(v))
    }

    fn visit_i64<E: de::Error>(self, v: i64) -> std::result::Result<Weight, E> {
        self.visit_f64(v as f64)
    }

    fn visit_u64<E: de::Error>(self, v: u64) -> std::result::Result<Weight, E> {
        self.visit_f64(v as f64)
    }

    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> std::result::Result<Weight, A::Error> {
        let (mut initial, mut until, mut shape) = (None, None, DecayShape::Linear);
        while let Some(key) = map.next_key::<String>()? {
            match key.as_str() {
                "decay_to_zero" => initial = Some(map.next_value::<f64>()?),
                "until" => until = Some(map.next_value::<f64>()?),
                "shape" => shape = map.next_value()?,
                other => return Err(de::Error::unknown_field(other, DECAY_FIELDS)),
            }
        }
        let initial = initial.ok_or_else(|| de::Error::missing_field("decay_to_zero"))?;
        let until = until.ok_or_else(|| de::Error::missing_field("until"))?;
        Self::checked(Weight::Decay { initial, until, shape })
    }
}

/// Where a piece of the file is, for messages.
struct Source<'a> {
    text: &'a str,
    origin: &'a str,
}

impl Source<'_> {
    /// 1-based line and column (bytes) of a byte offset.
    fn line_column(&self, offset: usize) -> (usize, usize) {
        let before = &self.text[..offset];
        let line_start = before.rfind('\n').map_or(0, |i| i + 1);
        (before.matches('\n').count() + 1, offset - line_start + 1)
    }

    /// The byte offset of `part`, a slice of the text.
    fn offset_of(&self, part: &str) -> usize {
        part.as_ptr() as usize - self.text.as_ptr() as usize
    }

    fn error(&self, field: Option<String>, (line, column): (usize, usize), rule: &str) -> RenderError {
        let rule = format!("line {line}, column {column}: {rule}");
        match field {
            Some(field) => RenderError::field(self.origin, field, rule),
            None => RenderError::file(self.origin, rule),
        }
    }

    /// A serde error in `part` (a slice of the text), at its place in the whole file.
    fn serde_error(&self, field: Option<String>, part: &str, e: &serde_json::Error) -> RenderError {
        let (line, column) = self.line_column(self.offset_of(part));
        let position = match e.line() {
            0 => (line, column),
            1 => (line, column + e.column() - 1),
            l => (line + l - 1, e.column()),
        };
        let message = e.to_string();
        let message = message.rsplit_once(" at line ").map_or(message.as_str(), |(m, _)| m);
        self.error(field, position, message)
    }

    /// The error for field `key` of the term whose raw text is `raw`, at the key's line.
    fn field_error(&self, index: usize, raw: &str, key: &str, rule: &str) -> RenderError {
        let quoted = format!("\"{key}\"");
        let at = raw.find(&quoted).unwrap_or(0);
        let position = self.line_column(self.offset_of(raw) + at);
        self.error(Some(format!("terms[{index}].{key}")), position, rule)
    }
}

impl TermSpec {
    /// Fails on a field that does not apply to the term, or a missing one.
    fn build(self, index: usize, raw: &str, source: &Source) -> Result<WeightedTerm> {
        let name = self.term.name();
        let misplaced = |key: &str, owner: &str| {
            source.field_error(
                index,
                raw,
                key,
                &format!("does not apply to `{name}` (only to `{owner}`)"),
            )
        };
        if self.term != TermKind::RgbL1 && self.variant.is_some() {
            return Err(misplaced("variant", "rgb_l1").into());
        }
        if self.term != TermKind::LightSmoothness {
            if self.sigma_deg.is_some() {
                return Err(misplaced("sigma_deg", "light_smoothness").into());
            }
            if self.directions.is_some() {
                return Err(misplaced("directions", "light_smoothness").into());
            }
        }
        if self.term != TermKind::NeighbourSmoothness {
            if self.edge.is_some() {
                return Err(misplaced("edge", "neighbour_smoothness").into());
            }
            if self.chroma.is_some() {
                return Err(misplaced("chroma", "neighbour_smoothness").into());
            }
        }
        let weight = self.weight.unwrap_or(Weight::Constant(1.0));
        let term = match self.term {
            TermKind::RgbL1 => RgbL1::new(self.variant.unwrap_or(RgbVariant::Relative)).weight(weight),
            TermKind::MaskL1 => MaskL1.weight(weight),
            TermKind::Chamfer => Chamfer.weight(weight),
            TermKind::Barycenter => Barycenter.weight(weight),
            TermKind::Orientation => OrientationPrior::front_facing().weight(weight),
            TermKind::LightSmoothness => {
                let sigma_deg = self
                    .sigma_deg
                    .ok_or_else(|| source.field_error(index, raw, "term", "`light_smoothness` needs `sigma_deg`"))?;
                let term = LightSmoothness::new(sigma_deg);
                let term = self.directions.map_or(term, |n| term.directions(n));
                term.validate().map_err(|e| {
                    let key = e.field_name().unwrap_or("sigma_deg");
                    source.field_error(index, raw, key, &e.rule())
                })?;
                term.weight(weight)
            }
            TermKind::DataLeastSquares => LeastSquaresData.weight(weight),
            TermKind::NeighbourSmoothness => {
                let term =
                    NeighbourSmoothness::charbonnier(self.edge.unwrap_or(0.0)).chroma(self.chroma.unwrap_or(1.0));
                term.validate().map_err(|e| {
                    let key = e.field_name().unwrap_or("edge");
                    source.field_error(index, raw, key, &e.rule())
                })?;
                term.weight(weight)
            }
            TermKind::LatitudePrior => LatitudePrior.weight(weight),
        };
        Ok(match self.phases {
            None => term,
            Some(phases) => term.in_phases(phases.into_iter().fold(Phases::NONE, Phases::with)),
        })
    }
}

impl Objective {
    /// Parses an objective from JSON text, so that terms and weights change
    /// without recompiling; `origin` names the text in messages (a file name).
    ///
    /// ```json
    /// {"terms": [
    ///   {"term": "rgb_l1", "variant": "log"},
    ///   {"term": "mask_l1"},
    ///   {"term": "chamfer", "weight": 0.5},
    ///   {"term": "barycenter", "weight": {"decay_to_zero": 10.0, "until": 0.5}},
    ///   {"term": "orientation", "weight": {"decay_to_zero": 0.1, "until": 1.0, "shape": "cosine"}},
    ///   {"term": "data_least_squares"},
    ///   {"term": "neighbour_smoothness", "edge": 0.05, "chroma": 1.0, "weight": 1e-2},
    ///   {"term": "light_smoothness", "sigma_deg": 2.0, "directions": 1024, "weight": 1e-3},
    ///   {"term": "latitude_prior", "weight": 1e-3}
    /// ]}
    /// ```
    ///
    /// A term's `weight` is 1 when left out, a number, or a decay to zero
    /// (`shape` linear, the default, or cosine); `variant` (rgb_l1 only) is
    /// relative (the default), plain, log or tonemapped; `sigma_deg` is
    /// required by light_smoothness, `directions` optional (1024); `edge`
    /// (0: quadratic) and `chroma` (1) are neighbour_smoothness's. Any term
    /// may say which `phases` evaluate it (`["pose"]`, `["lighting"]` or
    /// both; by default its own: the data and smoothness terms the
    /// lighting phase, the rest the pose phases).
    /// `assets/objectives/paper_default.json` is [`Objective::paper_default`].
    ///
    /// Unknown terms or fields, a field that does not apply to its term,
    /// and invalid weights or settings are errors naming the line:
    ///
    /// ```
    /// use alp::objective::Objective;
    /// let text = "{\"terms\": [\n  {\"term\": \"mask_l1\"},\n  {\"term\": \"chamfer\", \"weight\": -1}\n]}";
    /// let e = Objective::from_json_str(text, "objective.json").unwrap_err();
    /// assert!(e.to_string().contains("line 3"), "{e}");
    /// ```
    pub fn from_json_str(text: &str, origin: &str) -> Result<Self> {
        let source = Source { text, origin };
        let file: FileSpec = serde_json::from_str(text).map_err(|e| source.serde_error(None, text, &e))?;
        let mut objective = Objective::new();
        for (index, raw) in file.terms.iter().enumerate() {
            let raw = raw.get();
            let spec: TermSpec =
                serde_json::from_str(raw).map_err(|e| source.serde_error(Some(format!("terms[{index}]")), raw, &e))?;
            objective = objective.term(spec.build(index, raw, &source)?);
        }
        objective.validate().map_err(|e| e.in_file(origin))?;
        Ok(objective)
    }

    /// Reads an objective file (see [`from_json_str`](Self::from_json_str)).
    pub fn from_file(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|e| RenderError::io(path, "read the objective", e))?;
        Self::from_json_str(&text, &path.display().to_string())
    }
}
