//! Synthetic scenes: a TOML file (`deny_unknown_fields`) parsed once into a
//! validated [`Scene`]: textured ground, boxes (buildings), ellipsoids (tree
//! crowns), sky, and the survey line it is meant to be flown with. Errors name
//! the field and its line. The format is documented in `docs/scenes.md`.

mod texture;

pub use texture::Texture;

use serde::Deserialize;
use std::path::Path;
use thiserror::Error;

/// A scene file that cannot be used: the file, the field path
/// (`box[2].max_m`), the line (1-based, where known) and what is wrong.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum SceneError {
    #[error("cannot read scene {path}: {message}")]
    Read { path: String, message: String },
    #[error("scene {path}: line {line}: {field}: {message}", line = line.map_or("?".to_string(), |l| l.to_string()))]
    Field {
        path: String,
        field: String,
        line: Option<usize>,
        message: String,
    },
}

impl SceneError {
    /// The field path of a field error (`survey.altitude_m`), for tests and tools.
    pub fn field(&self) -> Option<&str> {
        match self {
            SceneError::Field { field, .. } => Some(field),
            SceneError::Read { .. } => None,
        }
    }
    pub fn line(&self) -> Option<usize> {
        match self {
            SceneError::Field { line, .. } => *line,
            SceneError::Read { .. } => None,
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawScene {
    name: String,
    #[serde(default)]
    description: String,
    survey: RawSurvey,
    #[serde(default)]
    sky: Option<RawSky>,
    ground: Option<RawGround>,
    #[serde(default, rename = "box")]
    boxes: Vec<RawBox>,
    #[serde(default, rename = "ellipsoid")]
    ellipsoids: Vec<RawEllipsoid>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSurvey {
    altitude_m: f64,
    speed_mps: f64,
    #[serde(default)]
    pitch_deg: f64,
    hfov_deg: f64,
    width: i64,
    height: i64,
    start_x_m: f64,
    end_x_m: f64,
    #[serde(default)]
    y_m: f64,
    view_step_m: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSky {
    colour: [f64; 3],
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawTexture {
    colour: [f64; 3],
    #[serde(default)]
    contrast: f64,
    #[serde(default = "default_cutoff")]
    cutoff_per_m: f64,
    #[serde(default)]
    seed: u64,
}

fn default_cutoff() -> f64 {
    1.0
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawGround {
    #[serde(default)]
    z_m: f64,
    texture: RawTexture,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawBox {
    min_m: [f64; 3],
    max_m: [f64; 3],
    texture: RawTexture,
    roof_texture: Option<RawTexture>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawEllipsoid {
    centre_m: [f64; 3],
    radii_m: [f64; 3],
    texture: RawTexture,
}

/// The survey line: the camera flies along `+x` at `y_m`, `altitude_m` above
/// `z = 0`, from `start_x_m` to `end_x_m`; dense ground-truth views every
/// `view_step_m`.
#[derive(Debug, Clone, PartialEq)]
pub struct Survey {
    pub altitude_m: f64,
    pub speed_mps: f64,
    pub pitch_rad: f64,
    pub hfov_deg: f64,
    pub width: usize,
    pub height: usize,
    pub start_x_m: f64,
    pub end_x_m: f64,
    pub y_m: f64,
    pub view_step_m: f64,
}

impl Survey {
    /// Number of dense views from start to end (both included).
    pub fn view_count(&self) -> usize {
        ((self.end_x_m - self.start_x_m) / self.view_step_m + 1e-9).floor() as usize + 1
    }
    pub fn view_x_m(&self, k: usize) -> f64 {
        self.start_x_m + k as f64 * self.view_step_m
    }
}

#[derive(Debug, Clone, PartialEq)]
pub struct Ground {
    pub z_m: f64,
    pub texture: Texture,
}

/// An axis-aligned box standing anywhere: walls get `texture`, the top face
/// `roof`.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneBox {
    pub min_m: [f64; 3],
    pub max_m: [f64; 3],
    pub texture: Texture,
    pub roof: Texture,
}

#[derive(Debug, Clone, PartialEq)]
pub struct Ellipsoid {
    pub centre_m: [f64; 3],
    pub radii_m: [f64; 3],
    pub texture: Texture,
}

#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    pub name: String,
    pub description: String,
    pub survey: Survey,
    pub sky_rgb: [f32; 3],
    pub ground: Option<Ground>,
    pub boxes: Vec<SceneBox>,
    pub ellipsoids: Vec<Ellipsoid>,
}

impl Scene {
    /// Multiplies every texture's cut-off by `factor` (same waves, scaled): a
    /// run at a lower resolution keeps the textures' bandwidth relative to the
    /// pixel Nyquist rate.
    pub fn scale_textures(&mut self, factor: f64) {
        let scale = |t: &mut Texture| {
            *t = Texture::new(t.colour, t.contrast, t.cutoff_per_m * factor, t.seed)
        };
        if let Some(g) = &mut self.ground {
            scale(&mut g.texture);
        }
        for b in &mut self.boxes {
            scale(&mut b.texture);
            scale(&mut b.roof);
        }
        for e in &mut self.ellipsoids {
            scale(&mut e.texture);
        }
    }

    /// Reads and validates a scene file.
    pub fn load(path: &Path) -> Result<Scene, SceneError> {
        let text = std::fs::read_to_string(path).map_err(|e| SceneError::Read {
            path: path.display().to_string(),
            message: e.to_string(),
        })?;
        Scene::parse(&text, &path.display().to_string())
    }

    /// Parses scene text; `path` only labels errors.
    pub fn parse(text: &str, path: &str) -> Result<Scene, SceneError> {
        let raw: RawScene = toml::from_str(text).map_err(|e| {
            let line = e.span().map(|s| line_of(text, s.start));
            let field = line
                .and_then(|l| field_at_line(text, l))
                .unwrap_or_else(|| "(document)".into());
            // toml's message repeats the snippet; keep its last line (the reason).
            let message = e.message().trim().to_string();
            let field = match message.strip_prefix("missing field `") {
                Some(rest) => {
                    let name = rest.split('`').next().unwrap_or("");
                    let table = line
                        .and_then(|l| table_at_line(text, l))
                        .unwrap_or_default();
                    if table.is_empty() {
                        name.to_string()
                    } else {
                        format!("{table}.{name}")
                    }
                }
                None => field,
            };
            SceneError::Field {
                path: path.to_string(),
                field,
                line,
                message,
            }
        })?;
        validate(raw, text, path)
    }
}

fn line_of(text: &str, byte: usize) -> usize {
    text[..byte.min(text.len())].matches('\n').count() + 1
}

/// The table header in force at `line` (`survey`, `box[1]`), empty at top level.
fn table_at_line(text: &str, line: usize) -> Option<String> {
    let mut current = String::new();
    let mut counts: std::collections::HashMap<String, usize> = Default::default();
    for (i, l) in text.lines().enumerate() {
        if i + 1 > line {
            break;
        }
        let t = l.trim();
        if let Some(name) = t.strip_prefix("[[").and_then(|r| r.split("]]").next()) {
            let name = name.trim().to_string();
            let n = counts.entry(name.clone()).or_insert(0);
            current = format!("{name}[{n}]");
            *n += 1;
        } else if let Some(name) = t.strip_prefix('[').and_then(|r| r.split(']').next()) {
            current = name.trim().to_string();
        }
    }
    Some(current)
}

/// `table.key` for the key assigned on `line`, if the line assigns one.
fn field_at_line(text: &str, line: usize) -> Option<String> {
    let l = text.lines().nth(line - 1)?;
    let table = table_at_line(text, line).unwrap_or_default();
    let key = l.split('=').next()?.trim();
    if key.is_empty() || key.starts_with('[') || !l.contains('=') {
        return Some(if table.is_empty() {
            "(document)".into()
        } else {
            table
        });
    }
    Some(if table.is_empty() {
        key.to_string()
    } else {
        format!("{table}.{key}")
    })
}

/// The line of `key` inside table `table` (`box[1]`, `""` for top level).
fn line_of_field(text: &str, table: &str, key: &str) -> Option<usize> {
    for (i, l) in text.lines().enumerate() {
        let line = i + 1;
        if table_at_line(text, line).as_deref() != Some(table) {
            continue;
        }
        let t = l.trim();
        if t.starts_with('[') {
            if key.is_empty() {
                return Some(line);
            }
            continue;
        }
        if let Some((k, _)) = t.split_once('=') {
            if k.trim() == key {
                return Some(line);
            }
        }
    }
    None
}

struct Checker<'a> {
    text: &'a str,
    path: &'a str,
}

impl Checker<'_> {
    fn fail(&self, table: &str, key: &str, message: String) -> SceneError {
        let line =
            line_of_field(self.text, table, key).or_else(|| line_of_field(self.text, table, ""));
        SceneError::Field {
            path: self.path.to_string(),
            field: if table.is_empty() {
                key.to_string()
            } else {
                format!("{table}.{key}")
            },
            line,
            message,
        }
    }

    fn range(&self, table: &str, key: &str, x: f64, lo: f64, hi: f64) -> Result<f64, SceneError> {
        if x.is_finite() && x >= lo && x <= hi {
            Ok(x)
        } else {
            Err(self.fail(table, key, format!("must be in [{lo}, {hi}], got {x}")))
        }
    }

    fn finite3(&self, table: &str, key: &str, v: [f64; 3]) -> Result<[f64; 3], SceneError> {
        if v.iter().all(|x| x.is_finite() && x.abs() <= 1e6) {
            Ok(v)
        } else {
            Err(self.fail(
                table,
                key,
                format!("must be three finite numbers within ±1e6 m, got {v:?}"),
            ))
        }
    }

    fn texture(&self, table: &str, key: &str, t: &RawTexture) -> Result<Texture, SceneError> {
        for c in t.colour {
            if !(0.0..=1.0).contains(&c) {
                return Err(self.fail(
                    table,
                    key,
                    format!("colour components must be in [0, 1], got {:?}", t.colour),
                ));
            }
        }
        if !(0.0..=1.0).contains(&t.contrast) {
            return Err(self.fail(
                table,
                key,
                format!("contrast must be in [0, 1], got {}", t.contrast),
            ));
        }
        if !(t.cutoff_per_m.is_finite() && t.cutoff_per_m > 0.0 && t.cutoff_per_m <= 1e3) {
            return Err(self.fail(
                table,
                key,
                format!(
                    "cutoff_per_m must be in (0, 1000] cycles per metre, got {}",
                    t.cutoff_per_m
                ),
            ));
        }
        Ok(Texture::new(
            [t.colour[0] as f32, t.colour[1] as f32, t.colour[2] as f32],
            t.contrast as f32,
            t.cutoff_per_m,
            t.seed,
        ))
    }
}

fn validate(raw: RawScene, text: &str, path: &str) -> Result<Scene, SceneError> {
    let c = Checker { text, path };
    if raw.name.trim().is_empty() {
        return Err(c.fail("", "name", "must not be empty".into()));
    }
    let s = &raw.survey;
    let t = "survey";
    let altitude_m = c.range(t, "altitude_m", s.altitude_m, 0.1, 1e4)?;
    let speed_mps = c.range(t, "speed_mps", s.speed_mps, 0.01, 1e3)?;
    let pitch_deg = c.range(t, "pitch_deg", s.pitch_deg, -80.0, 80.0)?;
    let hfov_deg = c.range(t, "hfov_deg", s.hfov_deg, 1.0, 170.0)?;
    let width = c.range(t, "width", s.width as f64, 8.0, 8192.0)? as usize;
    let height = c.range(t, "height", s.height as f64, 8.0, 8192.0)? as usize;
    let start_x_m = c.range(t, "start_x_m", s.start_x_m, -1e6, 1e6)?;
    let end_x_m = c.range(t, "end_x_m", s.end_x_m, -1e6, 1e6)?;
    if end_x_m <= start_x_m {
        return Err(c.fail(
            t,
            "end_x_m",
            format!("must be beyond start_x_m ({start_x_m}), got {end_x_m}"),
        ));
    }
    let y_m = c.range(t, "y_m", s.y_m, -1e6, 1e6)?;
    let view_step_m = c.range(t, "view_step_m", s.view_step_m, 1e-4, 1e3)?;
    if (end_x_m - start_x_m) / view_step_m > 1e5 {
        return Err(c.fail(
            t,
            "view_step_m",
            format!("gives more than 100000 views over the line, got {view_step_m}"),
        ));
    }
    let sky_rgb = match &raw.sky {
        Some(sky) => {
            if !sky.colour.iter().all(|v| (0.0..=1.0).contains(v)) {
                return Err(c.fail(
                    "sky",
                    "colour",
                    format!("components must be in [0, 1], got {:?}", sky.colour),
                ));
            }
            [
                sky.colour[0] as f32,
                sky.colour[1] as f32,
                sky.colour[2] as f32,
            ]
        }
        None => [0.62, 0.74, 0.92],
    };
    let ground = match &raw.ground {
        Some(g) => {
            let z_m = c.range("ground", "z_m", g.z_m, -1e4, 1e4)?;
            if z_m >= altitude_m {
                return Err(c.fail(
                    "ground",
                    "z_m",
                    format!("must be below the survey altitude ({altitude_m} m), got {z_m}"),
                ));
            }
            Some(Ground {
                z_m,
                texture: c.texture("ground", "texture", &g.texture)?,
            })
        }
        None => None,
    };
    let mut boxes = Vec::new();
    for (i, b) in raw.boxes.iter().enumerate() {
        let t = format!("box[{i}]");
        let min_m = c.finite3(&t, "min_m", b.min_m)?;
        let max_m = c.finite3(&t, "max_m", b.max_m)?;
        if (0..3).any(|k| max_m[k] <= min_m[k]) {
            return Err(c.fail(
                &t,
                "max_m",
                format!("must exceed min_m {min_m:?} on every axis, got {max_m:?}"),
            ));
        }
        let texture = c.texture(&t, "texture", &b.texture)?;
        let roof = match &b.roof_texture {
            Some(r) => c.texture(&t, "roof_texture", r)?,
            None => texture.clone(),
        };
        boxes.push(SceneBox {
            min_m,
            max_m,
            texture,
            roof,
        });
    }
    let mut ellipsoids = Vec::new();
    for (i, e) in raw.ellipsoids.iter().enumerate() {
        let t = format!("ellipsoid[{i}]");
        let centre_m = c.finite3(&t, "centre_m", e.centre_m)?;
        let radii_m = c.finite3(&t, "radii_m", e.radii_m)?;
        if radii_m.iter().any(|r| *r <= 0.0) {
            return Err(c.fail(&t, "radii_m", format!("must be positive, got {radii_m:?}")));
        }
        ellipsoids.push(Ellipsoid {
            centre_m,
            radii_m,
            texture: c.texture(&t, "texture", &e.texture)?,
        });
    }
    Ok(Scene {
        name: raw.name,
        description: raw.description,
        survey: Survey {
            altitude_m,
            speed_mps,
            pitch_rad: pitch_deg.to_radians(),
            hfov_deg,
            width,
            height,
            start_x_m,
            end_x_m,
            y_m,
            view_step_m,
        },
        sky_rgb,
        ground,
        boxes,
        ellipsoids,
    })
}
