//! Perturbation suites: named, versioned lists of variants (`suites/*.json`, compiled in), each
//! variant a set of dimensions at a level (`light_intensity=2`, `smoke=1,blur=1`), the
//! dimensions and their levels' ranges defined once in `suites/dimensions-v1.json`.
//!
//! A trial of a variant is the unperturbed trial (same task, same scene seed) with the variant
//! drawn from that seed ([`Variant::draw`], each dimension from a stream of its own) and applied
//! at reset: visual dimensions change the appearance, camera and image effects only (never the
//! physics), scene dimensions the spawn and the instrument's start, language dimensions the
//! instruction. Every policy sees the same draws, and each trial records the numbers it drew.
//!
//! Files never change meaning: `tests` pins each file's CRC-32, so a change must be a new file
//! (`visual-v2.json`); results record the suite, its dimensions file and that checksum.

use crate::assets::{Appearance, MaskClass};
use crate::render::{Camera, ImageEffects};
use crate::rng::SplitMix64;
use crate::task::{InstructionChoice, TaskConfig, TaskInstance};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::sync::OnceLock;

/// The dimensions file every suite of this version refers to.
pub const DIMENSIONS_FILE: (&str, &str) = (
    "dimensions-v1",
    include_str!("../../suites/dimensions-v1.json"),
);

/// The suites, by name, with their files' text.
pub const SUITE_FILES: [(&str, &str); 7] = [
    ("visual-v1", include_str!("../../suites/visual-v1.json")),
    (
        "visual-levels-v1",
        include_str!("../../suites/visual-levels-v1.json"),
    ),
    ("scene-v1", include_str!("../../suites/scene-v1.json")),
    ("language-v1", include_str!("../../suites/language-v1.json")),
    (
        "prompts-paraphrase-v1",
        include_str!("../../suites/prompts-paraphrase-v1.json"),
    ),
    (
        "prompts-detailed-v1",
        include_str!("../../suites/prompts-detailed-v1.json"),
    ),
    ("all-v1", include_str!("../../suites/all-v1.json")),
];

/// Which part of a trial a dimension changes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// The images only.
    Visual,
    /// The scene's layout or the instrument's start.
    Scene,
    /// The instruction.
    Language,
}

/// One dimension as its file states it.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
pub struct DimensionSpec {
    pub name: String,
    pub what: String,
    pub unit: String,
    /// The magnitudes collection draws from (`[0, 0]`: never varied in training).
    pub training: [f64; 2],
    /// Each level's range of magnitudes, level 1 first.
    pub levels: Vec<[f64; 2]>,
}

#[derive(Deserialize)]
struct DimensionsFile {
    dimensions: String,
    visual: Vec<DimensionSpec>,
    scene: Vec<DimensionSpec>,
    language: Vec<DimensionSpec>,
}

/// The dimensions of one dimensions file.
#[derive(Clone, Debug)]
pub struct Dimensions {
    pub name: String,
    pub specs: Vec<(Kind, DimensionSpec)>,
}

impl Dimensions {
    /// `dimensions-v1` (parsed once; `tests` checks it parses).
    pub fn v1() -> &'static Dimensions {
        static DIMENSIONS: OnceLock<Dimensions> = OnceLock::new();
        DIMENSIONS.get_or_init(|| {
            let file: DimensionsFile =
                serde_json::from_str(DIMENSIONS_FILE.1).unwrap_or_else(|_| DimensionsFile {
                    dimensions: DIMENSIONS_FILE.0.into(),
                    visual: Vec::new(),
                    scene: Vec::new(),
                    language: Vec::new(),
                });
            let tag = |kind, specs: Vec<DimensionSpec>| specs.into_iter().map(move |s| (kind, s));
            let specs = tag(Kind::Visual, file.visual)
                .chain(tag(Kind::Scene, file.scene))
                .chain(tag(Kind::Language, file.language))
                .collect();
            Dimensions {
                name: file.dimensions,
                specs,
            }
        })
    }

    /// The dimension named `name`.
    pub fn get(&self, name: &str) -> Option<&(Kind, DimensionSpec)> {
        self.specs.iter().find(|(_, s)| s.name == name)
    }

    /// Every dimension's name, in file order.
    pub fn names(&self) -> Vec<&str> {
        self.specs.iter().map(|(_, s)| s.name.as_str()).collect()
    }
}

/// A variant that cannot be read.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PerturbError {
    #[error("`{given}` is not DIMENSION=LEVEL (e.g. `light_intensity=2,blur=1`)")]
    Syntax { given: String },
    #[error("unknown perturbation dimension `{name}`; the dimensions are: {known}")]
    UnknownDimension { name: String, known: String },
    #[error("`{name}` has levels 1 to {levels}, not {level}")]
    Level {
        name: String,
        level: u32,
        levels: usize,
    },
    #[error("`{name}` is given twice in `{given}`")]
    Twice { name: String, given: String },
    #[error("unknown suite `{0}`")]
    UnknownSuite(String),
}

impl crate::error::HasKind for PerturbError {
    fn kind(&self) -> crate::error::ErrorKind {
        crate::error::ErrorKind::Usage
    }
}

/// A set of dimensions at their levels; empty: the unperturbed trial ("none").
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Variant {
    pub settings: Vec<(String, u32)>,
}

impl Variant {
    /// The variant's name: `none`, or `dim=level` joined by commas as given.
    pub fn name(&self) -> String {
        if self.settings.is_empty() {
            return "none".into();
        }
        let parts: Vec<String> = (self.settings.iter())
            .map(|(d, l)| format!("{d}={l}"))
            .collect();
        parts.join(",")
    }

    /// Reads `none` or `dim=level[,dim=level...]` against `dimensions`.
    pub fn parse(given: &str, dimensions: &Dimensions) -> Result<Variant, PerturbError> {
        let given = given.trim();
        if given == "none" {
            return Ok(Variant::default());
        }
        let mut settings: Vec<(String, u32)> = Vec::new();
        for part in given.split(',') {
            let syntax = || PerturbError::Syntax {
                given: given.into(),
            };
            let (name, level) = part.trim().split_once('=').ok_or_else(syntax)?;
            let level: u32 = level.trim().parse().map_err(|_| syntax())?;
            let name = name.trim();
            let Some((_, spec)) = dimensions.get(name) else {
                return Err(PerturbError::UnknownDimension {
                    name: name.into(),
                    known: dimensions.names().join(", "),
                });
            };
            if level == 0 || level as usize > spec.levels.len() {
                return Err(PerturbError::Level {
                    name: name.into(),
                    level,
                    levels: spec.levels.len(),
                });
            }
            if settings.iter().any(|(d, _)| d == name) {
                return Err(PerturbError::Twice {
                    name: name.into(),
                    given: given.into(),
                });
            }
            settings.push((name.to_string(), level));
        }
        Ok(Variant { settings })
    }

    /// Whether every dimension of the variant only changes images (true for "none").
    pub fn is_visual(&self, dimensions: &Dimensions) -> bool {
        (self.settings.iter())
            .all(|(d, _)| dimensions.get(d).is_some_and(|(k, _)| *k == Kind::Visual))
    }

    /// The variant drawn for the trial whose scene seed is `seed`.
    pub fn draw(&self, dimensions: &Dimensions, seed: u64) -> Drawn {
        let mut drawn = Drawn::default();
        for (name, level) in &self.settings {
            let Some((_, spec)) = dimensions.get(name) else {
                continue;
            };
            let Some(&[lo, hi]) = spec.levels.get(*level as usize - 1) else {
                continue;
            };
            let mut rng = SplitMix64::stream(seed, &format!("perturb/{name}"));
            drawn.apply(name, (lo, hi), &mut rng);
        }
        drawn
    }
}

/// What a variant does to one trial.
#[derive(Clone, Debug, PartialEq)]
pub struct Drawn {
    pub appearance: Appearance,
    pub effects: ImageEffects,
    /// The endoscope's move, in its own frame (None: where it is).
    pub camera_move: Option<Isometry3<f64>>,
    /// Multiplies the evaluation's spawn scale.
    pub spawn_factor: f64,
    pub distractors: Option<usize>,
    /// Added to the instrument tip's start, world, metres.
    pub tip_offset_m: Option<Vector3<f64>>,
    pub instruction: Option<InstructionChoice>,
    /// The numbers drawn, named with their units (what results record).
    pub values: BTreeMap<String, serde_json::Value>,
}

impl Default for Drawn {
    fn default() -> Self {
        Drawn {
            appearance: Appearance::default(),
            effects: ImageEffects::default(),
            camera_move: None,
            spawn_factor: 1.0,
            distractors: None,
            tip_offset_m: None,
            instruction: None,
            values: BTreeMap::new(),
        }
    }
}

/// To the millionth: the figure, not float noise.
fn rounded(v: f64) -> serde_json::Value {
    serde_json::json!((v * 1e6).round() / 1e6)
}

fn sign(rng: &mut SplitMix64) -> f64 {
    if rng.next_f64() < 0.5 { -1.0 } else { 1.0 }
}

/// A unit vector uniform on the sphere.
fn direction(rng: &mut SplitMix64) -> Vector3<f64> {
    let z = rng.uniform(-1.0, 1.0);
    let a = rng.uniform(0.0, std::f64::consts::TAU);
    let r = (1.0 - z * z).max(0.0).sqrt();
    Vector3::new(r * a.cos(), r * a.sin(), z)
}

/// Each channel x (1 +- m), m drawn per channel.
fn tint(rng: &mut SplitMix64, (lo, hi): (f64, f64)) -> [f32; 3] {
    std::array::from_fn(|_| {
        let m = rng.uniform(lo, hi);
        (1.0 + sign(rng) * m) as f32
    })
}

impl Drawn {
    fn record(&mut self, key: &str, value: serde_json::Value) {
        self.values.insert(key.into(), value);
    }

    fn record_tint(&mut self, key: &str, tint: [f32; 3]) {
        let values: Vec<serde_json::Value> = tint.iter().map(|&t| rounded(f64::from(t))).collect();
        self.record(key, values.into());
    }

    fn apply(&mut self, name: &str, range: (f64, f64), rng: &mut SplitMix64) {
        let m = rng.uniform(range.0, range.1);
        if !self.apply_light_and_camera(name, m, rng) {
            self.apply_other(name, m, range, rng);
        }
    }

    /// The light's and the camera's dimensions (false: `name` is another).
    fn apply_light_and_camera(&mut self, name: &str, m: f64, rng: &mut SplitMix64) -> bool {
        match name {
            "light_intensity" => {
                let gain = 1.0 + sign(rng) * m;
                self.appearance.light_gain_scale = gain as f32;
                self.record("light_gain_scale", rounded(gain));
            }
            "light_colour" => {
                let s = sign(rng) * m;
                self.effects.light_tint = [(1.0 + s) as f32, 1.0, (1.0 - s) as f32];
                self.record_tint("light_tint_rgb", self.effects.light_tint);
            }
            "light_direction" => {
                let a = rng.uniform(0.0, std::f64::consts::TAU);
                self.effects.light_slope = [(m * a.cos()) as f32, (m * a.sin()) as f32];
                self.record("light_falloff", rounded(m));
                self.record("light_direction_deg", rounded(a.to_degrees()));
            }
            "camera_pose" => {
                let shift_m = direction(rng) * (m / 1000.0);
                let turn = UnitQuaternion::from_scaled_axis(direction(rng) * m.to_radians());
                self.camera_move = Some(Isometry3::from_parts(Translation3::from(shift_m), turn));
                self.record("camera_shift_mm", rounded(m));
                self.record("camera_turn_deg", rounded(m));
            }
            _ => return false,
        }
        true
    }

    /// Surfaces, image effects, the scene and the instruction.
    fn apply_other(&mut self, name: &str, m: f64, range: (f64, f64), rng: &mut SplitMix64) {
        match name {
            "tissue_colour" => {
                self.appearance.tissue_tint = tint(rng, range);
                self.record_tint("tissue_tint_rgb", self.appearance.tissue_tint);
            }
            "tissue_texture" => {
                let scale = (sign(rng) * m).exp2();
                self.appearance.texture_contrast_scale = scale as f32;
                self.record("texture_contrast_scale", rounded(scale));
            }
            "drape_colour" => {
                self.appearance.drape_tint = tint(rng, range);
                self.record_tint("drape_tint_rgb", self.appearance.drape_tint);
            }
            "smoke" => {
                self.effects.haze = m as f32;
                self.record("smoke_fraction", rounded(m));
            }
            "blood" => {
                self.effects.blood_coverage = m as f32;
                self.effects.blood_seed = rng.next_u64() as u32;
                self.effects.blood_classes = [
                    MaskClass::Table,
                    MaskClass::Tray,
                    MaskClass::Kidney,
                    MaskClass::Spleen,
                    MaskClass::Vessel,
                ]
                .iter()
                .fold(0, |bits, c| bits | 1 << c.id());
                self.record("blood_coverage", rounded(m));
            }
            "specular" => {
                self.appearance.specular_scale = (1.0 + m) as f32;
                self.record("specular_scale", rounded(1.0 + m));
            }
            "sensor_noise" => {
                self.effects.noise_sigma = m as f32;
                self.effects.noise_seed = rng.next_u64();
                self.record("noise_sigma_levels", rounded(m));
            }
            "blur" => {
                self.effects.blur_radius_px = m.round() as u32;
                self.record("blur_radius_px", (m.round() as u32).into());
            }
            "instrument_appearance" => {
                self.appearance.instrument_tint = tint(rng, range);
                self.record_tint("instrument_tint_rgb", self.appearance.instrument_tint);
            }
            "spawn_range" => {
                self.spawn_factor = 1.0 + m;
                self.record("spawn_scale_factor", rounded(1.0 + m));
            }
            "distractors" => {
                self.distractors = Some(m.round() as usize);
                self.record("distractors", (m.round() as u64).into());
            }
            "distractor_similarity" => {
                self.appearance.distractor_similarity = m as f32;
                self.record("distractor_similarity", rounded(m));
            }
            "instrument_start" => {
                let a = rng.uniform(0.0, std::f64::consts::TAU);
                let offset = Vector3::new(a.cos(), a.sin(), 0.0) * (m / 1000.0);
                self.tip_offset_m = Some(offset);
                self.record("tip_start_offset_mm", rounded(m));
                self.record("tip_start_direction_deg", rounded(a.to_degrees()));
            }
            "paraphrase" | "detailed" | "absent_object" => {
                let choice = match name {
                    "paraphrase" => InstructionChoice::Paraphrase,
                    "detailed" => InstructionChoice::Detailed,
                    _ => InstructionChoice::AbsentObject,
                };
                self.instruction = Some(choice);
                self.record("instructions", choice.name().into());
            }
            _ => {}
        }
    }

    /// The task options of the trial: the evaluation's, with the variant's spawn, distractors
    /// and instruction.
    pub fn task_config(&self, base: TaskConfig) -> TaskConfig {
        TaskConfig {
            spawn_scale: base.spawn_scale * self.spawn_factor,
            distractors: self.distractors.unwrap_or(base.distractors),
            instruction: self.instruction.unwrap_or(base.instruction),
            ..base
        }
    }

    /// Moves the instance's instrument start (when the variant does).
    pub fn apply_to_instance(&self, instance: &mut TaskInstance, default_tip_m: Vector3<f64>) {
        if let Some(offset) = self.tip_offset_m {
            let start = instance.scene.tip_start_m.unwrap_or(default_tip_m);
            instance.scene.tip_start_m = Some(start + offset);
        }
    }

    /// The trial's camera: `base` moved as the variant says.
    pub fn camera(&self, base: &Camera) -> Camera {
        match self.camera_move {
            Some(motion) => Camera {
                world_from_camera: base.world_from_camera * motion,
                ..*base
            },
            None => *base,
        }
    }
}

/// A suite as its file states it.
#[derive(Clone, Debug, Deserialize)]
struct SuiteFile {
    suite: String,
    dimensions: String,
    description: String,
    variants: Vec<String>,
}

/// A suite: its variants in order, and what results record of it.
#[derive(Clone, Debug, PartialEq)]
pub struct Suite {
    pub name: String,
    pub description: String,
    pub variants: Vec<Variant>,
    /// The dimensions file's name.
    pub dimensions: String,
    /// CRC-32 of the suite's file and of its dimensions file (what a third party checks).
    pub crc32: (u32, u32),
}

impl Suite {
    /// The built-in suite `name` (one of [`SUITE_FILES`]).
    pub fn builtin(name: &str) -> Result<Suite, PerturbError> {
        let (_, text) = SUITE_FILES
            .iter()
            .find(|(n, _)| *n == name)
            .ok_or_else(|| PerturbError::UnknownSuite(name.into()))?;
        let file: SuiteFile =
            serde_json::from_str(text).map_err(|_| PerturbError::UnknownSuite(name.into()))?;
        let dimensions = Dimensions::v1();
        let variants = (file.variants.iter())
            .map(|v| Variant::parse(v, dimensions))
            .collect::<Result<_, _>>()?;
        Ok(Suite {
            name: file.suite,
            description: file.description,
            variants,
            dimensions: file.dimensions,
            crc32: (
                crc32fast::hash(text.as_bytes()),
                crc32fast::hash(DIMENSIONS_FILE.1.as_bytes()),
            ),
        })
    }

    /// One-off variants given on the command line (`--perturb`), against `dimensions-v1`.
    pub fn one_off(variants: Vec<Variant>) -> Suite {
        Suite {
            name: "perturb".into(),
            description: "variants given with --perturb".into(),
            variants,
            dimensions: DIMENSIONS_FILE.0.into(),
            crc32: (0, crc32fast::hash(DIMENSIONS_FILE.1.as_bytes())),
        }
    }

    /// What results.json records of the suite.
    pub fn json(&self) -> serde_json::Value {
        let names: Vec<String> = self.variants.iter().map(Variant::name).collect();
        serde_json::json!({
            "name": self.name,
            "description": self.description,
            "dimensions": self.dimensions,
            "suite_file_crc32": format!("{:08x}", self.crc32.0),
            "dimensions_file_crc32": format!("{:08x}", self.crc32.1),
            "variants": names,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A file's text changes only with a new version: these are the files' checksums.
    const PINNED: [(&str, u32); 8] = [
        ("dimensions-v1", 0x1b444e38),
        ("visual-v1", 0x1e7c3d1e),
        ("visual-levels-v1", 0x877f1887),
        ("scene-v1", 0x6688a3ad),
        ("language-v1", 0x34c3a6d4),
        ("prompts-paraphrase-v1", 0x3c665939),
        ("prompts-detailed-v1", 0x324256fa),
        ("all-v1", 0x2f7fb2f1),
    ];

    #[test]
    fn suite_files_never_change_meaning() {
        let files = std::iter::once(DIMENSIONS_FILE).chain(SUITE_FILES);
        for ((name, text), (pinned_name, crc)) in files.zip(PINNED) {
            assert_eq!(name, pinned_name);
            assert_eq!(
                crc32fast::hash(text.as_bytes()),
                crc,
                "suites/{name}.json changed: a suite never changes meaning; add {name} as a new version instead"
            );
        }
    }

    #[test]
    fn every_suite_parses_and_levels_are_held_out_from_training() {
        let dims = Dimensions::v1();
        assert_eq!(dims.specs.len(), 20);
        for (kind, spec) in &dims.specs {
            assert!(!spec.levels.is_empty());
            for [lo, hi] in &spec.levels {
                assert!(lo <= hi, "{}", spec.name);
                if *kind != Kind::Language {
                    assert!(
                        *lo > spec.training[1],
                        "{}: level {lo}..{hi} overlaps training {:?}",
                        spec.name,
                        spec.training
                    );
                }
            }
        }
        for (name, _) in SUITE_FILES {
            let suite = Suite::builtin(name).unwrap();
            assert_eq!(suite.name, name);
            assert_eq!(
                suite.variants[0],
                Variant::default(),
                "{name} starts unperturbed"
            );
        }
        // Appearance::randomized (collect --randomize-appearance) draws inside the training
        // ranges, which the collection records as the file states them.
        for (name, range) in Appearance::TRAINING_RANGES {
            assert_eq!(dims.get(name).unwrap().1.training, range, "{name}");
        }
        let training = |n: &str| dims.get(n).unwrap().1.training[1];
        for seed in 0..200 {
            let a = Appearance::randomized(seed);
            assert!(
                f64::from((a.light_gain_scale - 1.0).abs()) <= training("light_intensity") + 1e-6
            );
            for t in a.tissue_tint {
                assert!(f64::from((t - 1.0).abs()) <= training("tissue_colour") + 1e-6);
            }
            assert!(f64::from(a.texture_contrast_scale.log2().abs()) <= training("tissue_texture"));
        }
    }

    #[test]
    fn variants_parse_with_clear_errors_and_draw_reproducibly() {
        let dims = Dimensions::v1();
        let v = Variant::parse("smoke=1, blur=3", dims).unwrap();
        assert_eq!(v.name(), "smoke=1,blur=3");
        assert!(v.is_visual(dims));
        assert!(
            !Variant::parse("spawn_range=1", dims)
                .unwrap()
                .is_visual(dims)
        );
        for (bad, says) in [
            ("smoke", "DIMENSION=LEVEL"),
            ("fog=1", "unknown perturbation dimension `fog`"),
            ("smoke=4", "levels 1 to 3, not 4"),
            ("smoke=0", "not 0"),
            ("smoke=1,smoke=2", "given twice"),
        ] {
            let e = Variant::parse(bad, dims).unwrap_err().to_string();
            assert!(e.contains(says), "{bad}: {e}");
        }
        let drawn = |seed| {
            Variant::parse("light_intensity=3,camera_pose=2", dims)
                .unwrap()
                .draw(dims, seed)
        };
        assert_eq!(drawn(4), drawn(4));
        assert_ne!(drawn(4), drawn(5));
        for seed in 0..50 {
            let d = drawn(seed);
            let gain = f64::from(d.appearance.light_gain_scale);
            assert!((0.55..=0.65).contains(&(gain - 1.0).abs()), "{gain}");
            let motion = d.camera_move.unwrap();
            let mm = motion.translation.vector.norm() * 1000.0;
            let deg = motion.rotation.angle().to_degrees();
            assert!((4.0..=5.0 + 1e-9).contains(&mm) && (4.0..=5.0 + 1e-9).contains(&deg));
            assert_eq!(d.values.len(), 3);
        }
        assert_eq!(Variant::default().draw(dims, 3), Drawn::default());
    }
}
