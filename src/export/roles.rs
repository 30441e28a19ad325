//! Roles for another tool's features (`convert --camera KEY --depth KEY`): zarr, MCAP, PLY and
//! PCD are built around one camera (and its depth, for point clouds), which surgvla's own
//! datasets name and another tool's do not. [`RoleSource`] wraps a source whose camera is one
//! of its image features: that feature's pixels become the steps' RGB, the depth feature's
//! values metres, the camera's size and intrinsics the dataset's camera, and the features the
//! target has no place for ([`Others`]) leave with a note naming each.

use crate::episode::{Dtype, Episode, FeatureKind, FeatureSpec, FeatureValue, Step};
use crate::export::error::ExportError;
use crate::export::info::DatasetInfo;
use crate::export::source::EpisodeSource;
use crate::media::image::{decode_8bit_sized, decode_png16_sized};
use crate::media::tiff::decode_f32_tiff;

/// Metres per unit of a 16-bit depth image when the user gives none (millimetres, as RLDS
/// datasets and depth cameras store it).
pub const DEFAULT_DEPTH_UNIT_M: f64 = 0.001;

/// Which of another tool's features play surgvla's camera and depth roles.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Roles {
    /// The RGB image feature that becomes the camera.
    pub camera: Option<String>,
    /// The depth image feature (16-bit grey PNG, or float TIFF in metres).
    pub depth: Option<String>,
    /// Metres per unit of a 16-bit depth image (default [`DEFAULT_DEPTH_UNIT_M`]).
    pub depth_unit_m: Option<f64>,
    /// The camera's pinhole intrinsics in pixels, as OpenCV's camera matrix holds them (pixel
    /// centres at integer coordinates): fx, fy, cx, cy (point clouds need them).
    pub intrinsics_px: Option<[f64; 4]>,
}

impl Roles {
    /// Whether no role is given.
    pub fn is_empty(&self) -> bool {
        *self == Roles::default()
    }
}

/// What a target keeps of the features that have no role in it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Others {
    /// Every feature (LeRobot, RLDS, MCAP).
    All,
    /// Numeric vectors, as arrays (zarr).
    Vectors,
    /// None: the target holds point clouds only (PLY, PCD).
    #[default]
    Nothing,
}

impl Others {
    /// Whether a target keeping these holds `feature`.
    pub fn hold(self, feature: &FeatureSpec) -> bool {
        match self {
            Others::All => true,
            Others::Vectors => matches!(feature.dtype, Dtype::Float32 | Dtype::Int64),
            Others::Nothing => false,
        }
    }
}

/// What becomes of one of the input's [`Step::other`] values.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Slot {
    Camera,
    Depth,
    Keep,
    Drop,
}

/// A source whose features play the roles [`Roles`] gives them (see the module's overview).
pub struct RoleSource {
    inner: Box<dyn EpisodeSource + Send>,
    info: DatasetInfo,
    /// Per value of the input's steps' `other`.
    slots: Vec<Slot>,
    /// The keys of the features given the camera and depth roles.
    roled: Vec<String>,
    depth_unit_m: f64,
}

/// A refusal of the user's choice of roles (exit 2).
fn usage(problem: String) -> ExportError {
    ExportError::InvalidOptions(problem)
}

impl RoleSource {
    /// `inner` with `roles` given, for a target titled `target` that keeps `others` of the
    /// remaining features. An input with a camera of its own (surgvla's) is passed through
    /// when no role is given; a named key that is not one of the input's image features, a
    /// depth of another size than the camera, and a target that needs a camera with none named
    /// are refused, listing the input's image features.
    pub fn new(
        inner: Box<dyn EpisodeSource + Send>,
        roles: &Roles,
        others: Others,
        target: &str,
    ) -> Result<Self, ExportError> {
        let input = inner.info();
        let images: Vec<&str> = (input.features.iter())
            .filter(|f| f.kind == FeatureKind::Other && f.dtype == Dtype::Image)
            .map(|f| f.name.as_str())
            .collect();
        let listed = if images.is_empty() {
            "the input has no image feature".to_string()
        } else {
            format!("its image features: {}", images.join(", "))
        };
        if let Some(own) = input.rgb_key().filter(|_| roles.camera.is_some()) {
            return Err(usage(format!(
                "--camera: the input names its camera already ({own})"
            )));
        }
        if roles.camera.is_none() && input.rgb_key().is_none() {
            return Err(usage(format!(
                "{target} is built around one camera, and another tool's dataset names none: --camera KEY names it ({listed})"
            )));
        }
        let find = |flag: &str, key: Option<&str>, channels: usize| {
            key.map(|key| find_image(input, &listed, flag, key, channels))
                .transpose()
        };
        let camera = find("--camera", roles.camera.as_deref(), 3)?;
        let depth = find("--depth", roles.depth.as_deref(), 1)?;
        let mut info = input.clone();
        let (slots, left_out) = assign(&mut info, camera, depth, others, target);
        info.notes.extend(left_out);
        let camera_notes = camera_of(&mut info, input, camera, depth, roles)?;
        info.notes.extend(camera_notes);
        let roled = [camera, depth]
            .into_iter()
            .flatten()
            .map(|i| input.features[i].name.clone())
            .collect();
        Ok(RoleSource {
            inner,
            info,
            slots,
            roled,
            depth_unit_m: roles.depth_unit_m.unwrap_or(DEFAULT_DEPTH_UNIT_M),
        })
    }

    /// The step with its values moved to their roles.
    fn cast(&self, step: &mut Step, index: u64, frame: usize) -> Result<(), ExportError> {
        let (width, height) = self.info.image_size();
        let bad = |what: &str, problem: String| {
            ExportError::InvalidEpisode(format!(
                "episode {index} frame {frame}: the {what}: {problem}"
            ))
        };
        let values = std::mem::take(&mut step.other);
        for (value, slot) in values.into_iter().zip(&self.slots) {
            match (slot, value) {
                (Slot::Keep, value) => step.other.push(value),
                (Slot::Drop, _) => {}
                (Slot::Camera, FeatureValue::Image(bytes)) => {
                    let (_, _, channels, pixels) = decode_8bit_sized(&bytes, Some((width, height)))
                        .map_err(|p| bad("camera", p))?;
                    if channels != 3 {
                        return Err(bad("camera", format!("{channels} channels, not 3")));
                    }
                    step.rgb = pixels;
                }
                (Slot::Depth, FeatureValue::Image(bytes)) => {
                    step.depth_m = self
                        .depth(&bytes, (width, height))
                        .map_err(|p| bad("depth", p))?;
                }
                (_, _) => return Err(bad("camera or depth", "not an image value".into())),
            }
        }
        Ok(())
    }

    /// A depth image's values in metres: a 16-bit grey PNG times the unit, or a float TIFF.
    fn depth(&self, bytes: &[u8], size: (usize, usize)) -> Result<Vec<f32>, String> {
        if let Some((w, h, metres)) = decode_f32_tiff(bytes) {
            if (w as usize, h as usize) != size {
                return Err(format!("a {w}x{h} image"));
            }
            return Ok(metres);
        }
        let (_, _, values) = decode_png16_sized(bytes, Some(size))?;
        let unit = self.depth_unit_m;
        Ok(values
            .into_iter()
            .map(|v| (f64::from(v) * unit) as f32)
            .collect())
    }
}

/// The index of the input's image feature `key` given a role by `flag`, with `channels`.
fn find_image(
    info: &DatasetInfo,
    listed: &str,
    flag: &str,
    key: &str,
    channels: usize,
) -> Result<usize, ExportError> {
    let position = (info.features.iter())
        .position(|f| f.name == key && f.kind == FeatureKind::Other && f.in_steps());
    match position {
        Some(i) if info.features[i].dtype == Dtype::Image => {
            let shape = &info.features[i].shape;
            let wanted = if channels == 3 {
                "3 channels (RGB)"
            } else {
                "1 channel (depth)"
            };
            if shape.len() == 3 && shape[2] == channels {
                Ok(i)
            } else {
                Err(usage(format!(
                    "{flag} {key}: an image of shape {shape:?}, where {wanted} was expected"
                )))
            }
        }
        _ => Err(usage(format!(
            "{flag} {key}: not an image feature of the input ({listed})"
        ))),
    }
}

/// Gives the features at `camera` and `depth` their roles in `info` and leaves out what
/// `others` does not hold: each step value's slot, and the note naming what was left out.
fn assign(
    info: &mut DatasetInfo,
    camera: Option<usize>,
    depth: Option<usize>,
    others: Others,
    target: &str,
) -> (Vec<Slot>, Option<String>) {
    let mut slots = Vec::new();
    let mut dropped = Vec::new();
    for (i, feature) in info.features.iter_mut().enumerate() {
        if feature.kind != FeatureKind::Other || !feature.in_steps() {
            continue;
        }
        let slot = if Some(i) == camera {
            feature.kind = FeatureKind::Rgb;
            Slot::Camera
        } else if Some(i) == depth {
            feature.kind = FeatureKind::Depth;
            Slot::Depth
        } else if others.hold(feature) {
            Slot::Keep
        } else {
            dropped.push(feature.name.clone());
            Slot::Drop
        };
        slots.push(slot);
    }
    info.features.retain(|f| !dropped.contains(&f.name));
    let kept = match others {
        Others::Vectors => "its numeric vectors are kept",
        _ => "it holds point clouds",
    };
    let note = (!dropped.is_empty()).then(|| {
        format!(
            "left out {}: {target} has no place for them ({kept}; LeRobot and RLDS keep every feature)",
            dropped.join(", ")
        )
    });
    (slots, note)
}

/// Sets `info`'s camera from the input's features at `camera` and `depth` and the given
/// intrinsics; the notes saying what the camera and depth are.
fn camera_of(
    info: &mut DatasetInfo,
    input: &DatasetInfo,
    camera: Option<usize>,
    depth: Option<usize>,
    roles: &Roles,
) -> Result<Vec<String>, ExportError> {
    let mut notes = Vec::new();
    if let Some(i) = camera {
        let shape = &input.features[i].shape;
        info.camera.height_px = shape[0] as u32;
        info.camera.width_px = shape[1] as u32;
        info.camera.world_from_camera = identity();
        notes.push(format!(
            "the camera is {} ({}x{}); the world frame is its optical frame",
            input.features[i].name, shape[1], shape[0]
        ));
    }
    let unit_m = roles.depth_unit_m.unwrap_or(DEFAULT_DEPTH_UNIT_M);
    if !(unit_m > 0.0 && unit_m.is_finite()) {
        return Err(usage("--depth-unit-m must be a positive number".into()));
    }
    if let Some(i) = depth {
        let (name, shape) = (&input.features[i].name, &input.features[i].shape);
        let (width, height) = (info.camera.width_px, info.camera.height_px);
        if (shape[1], shape[0]) != (width as usize, height as usize) {
            return Err(usage(format!(
                "--depth {name}: {}x{} images, where the camera's are {width}x{height}",
                shape[1], shape[0]
            )));
        }
        notes.push(format!(
            "the depth is {name}: 16-bit values times {unit_m} m (--depth-unit-m), float values in metres; 0 is no depth"
        ));
    }
    if let Some([fx, fy, cx, cy]) = roles.intrinsics_px {
        if !(fx > 0.0 && fy > 0.0 && cx.is_finite() && cy.is_finite()) {
            return Err(usage(
                "--intrinsics: fx and fy must be positive, cx and cy finite".into(),
            ));
        }
        // OpenCV's principal point puts pixel centres at integers; surgvla's at +0.5.
        (info.camera.fx_px, info.camera.fy_px) = (fx, fy);
        (info.camera.cx_px, info.camera.cy_px) = (cx + 0.5, cy + 0.5);
    }
    Ok(notes)
}

/// The 4x4 identity.
fn identity() -> [[f64; 4]; 4] {
    let mut m = [[0.0; 4]; 4];
    for (i, row) in m.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    m
}

impl Iterator for RoleSource {
    type Item = Result<Episode, ExportError>;

    fn next(&mut self) -> Option<Self::Item> {
        let mut episode = match self.inner.next()? {
            Ok(episode) => episode,
            Err(e) => return Some(Err(e)),
        };
        // The camera's and depth's stored bytes are pixels now; what was left out goes.
        let kept = &self.info.features;
        episode.encoded.retain(|e| {
            !self.roled.contains(&e.feature) && kept.iter().any(|f| f.name == e.feature)
        });
        let index = episode.meta.index;
        for (frame, step) in episode.steps.iter_mut().enumerate() {
            if let Err(e) = self.cast(step, index, frame) {
                return Some(Err(e));
            }
        }
        Some(Ok(episode))
    }
}

impl EpisodeSource for RoleSource {
    fn info(&self) -> &DatasetInfo {
        &self.info
    }

    fn len(&self) -> u64 {
        self.inner.len()
    }

    fn skip_episode(&mut self) -> Option<Result<(), ExportError>> {
        self.inner.skip_episode()
    }

    fn drop_stored(&mut self, unused: &[crate::episode::ImageEncoding]) {
        self.inner.drop_stored(unused);
    }
}
