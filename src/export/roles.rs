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
            Others::Vectors => matches!(
                feature.dtype,
                Dtype::Float32 | Dtype::Float64 | Dtype::Int64
            ),
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::episode::{EpisodeMeta, FeatureSpec};
    use crate::media::image::{PngLevel, encode_png, encode_png16};

    fn feature(name: &str, dtype: Dtype, shape: Vec<usize>) -> FeatureSpec {
        FeatureSpec {
            name: name.into(),
            dtype,
            shape,
            names: Vec::new(),
            kind: FeatureKind::Other,
            video: None,
            info: Default::default(),
        }
    }

    /// Another tool's dataset of one 2-step episode: a 4x3 camera, its 16-bit depth, a wrist
    /// camera and an action.
    struct Foreign {
        info: DatasetInfo,
        episodes: Vec<Episode>,
    }

    impl Iterator for Foreign {
        type Item = Result<Episode, ExportError>;
        fn next(&mut self) -> Option<Self::Item> {
            (!self.episodes.is_empty()).then(|| Ok(self.episodes.remove(0)))
        }
    }

    impl EpisodeSource for Foreign {
        fn info(&self) -> &DatasetInfo {
            &self.info
        }
        fn len(&self) -> u64 {
            1
        }
    }

    fn foreign() -> Box<dyn EpisodeSource + Send> {
        let features = vec![
            feature("action", Dtype::Float32, vec![2]),
            feature("observation.images.depth", Dtype::Image, vec![3, 4, 1]),
            feature("observation.images.image", Dtype::Image, vec![3, 4, 3]),
            feature("observation.images.wrist", Dtype::Image, vec![3, 4, 3]),
        ];
        let info = DatasetInfo::from_surgvla_json(&serde_json::Value::Null, 10, "", features);
        let steps = (0..2u8)
            .map(|t| {
                let rgb: Vec<u8> = (0..36).map(|i| i * 7 + t).collect();
                let mm: Vec<u16> = (0..12).map(|i| 1000 + 10 * i + u16::from(t)).collect();
                let mut step = Step::empty();
                step.other = vec![
                    FeatureValue::Float32(vec![f32::from(t), 1.0]),
                    FeatureValue::Image(encode_png16(4, 3, &mm, PngLevel::Fast).expect("png16")),
                    FeatureValue::Image(encode_png(4, 3, 3, &rgb, PngLevel::Fast).expect("png")),
                    FeatureValue::Image(encode_png(4, 3, 3, &rgb, PngLevel::Fast).expect("png")),
                ];
                step
            })
            .collect();
        let episode = Episode {
            meta: EpisodeMeta::foreign(0, "pick".into()),
            steps,
            encoded: Vec::new(),
            image_stats: Vec::new(),
            stored_rows: None,
        };
        Box::new(Foreign {
            info,
            episodes: vec![episode],
        })
    }

    fn roles(camera: &str, depth: Option<&str>) -> Roles {
        Roles {
            camera: Some(camera.into()),
            depth: depth.map(String::from),
            depth_unit_m: Some(0.5e-3),
            intrinsics_px: Some([100.0, 110.0, 1.5, 1.0]),
        }
    }

    #[test]
    fn the_named_camera_and_depth_become_pixels_and_metres_and_the_rest_is_kept_or_noted() {
        let named = roles("observation.images.image", Some("observation.images.depth"));
        let mut source =
            RoleSource::new(foreign(), &named, Others::Vectors, "zarr").expect("roles");
        let info = source.info().clone();
        assert_eq!(info.rgb_key(), Some("observation.images.image"));
        assert!(info.has(FeatureKind::Depth));
        assert_eq!((info.camera.width_px, info.camera.height_px), (4, 3));
        // OpenCV's principal point, in surgvla's pixel-centre convention.
        assert_eq!((info.camera.cx_px, info.camera.cy_px), (2.0, 1.5));
        let names: Vec<&str> = info.features.iter().map(|f| f.name.as_str()).collect();
        assert!(!names.contains(&"observation.images.wrist"), "{names:?}");
        assert!(
            info.notes
                .iter()
                .any(|n| n.starts_with("left out observation.images.wrist: zarr")),
            "{:?}",
            info.notes
        );
        let episode = source.next().expect("one").expect("read");
        let step = &episode.steps[1];
        assert_eq!(step.rgb, (0..36).map(|i| i * 7 + 1).collect::<Vec<u8>>());
        assert!(
            (step.depth_m[2] - 1021.0 * 0.5e-3).abs() < 1e-6,
            "{:?}",
            step.depth_m
        );
        assert_eq!(step.other, [FeatureValue::Float32(vec![1.0, 1.0])]);
        // MCAP keeps every other feature.
        let source = RoleSource::new(foreign(), &named, Others::All, "MCAP").expect("roles");
        assert!(
            source
                .info()
                .notes
                .iter()
                .all(|n| !n.starts_with("left out"))
        );
    }

    #[test]
    fn roles_that_do_not_fit_the_input_are_refused_naming_its_images() {
        let refused = |roles: Roles| {
            let error = RoleSource::new(foreign(), &roles, Others::All, "PLY")
                .err()
                .expect("refused");
            assert_eq!(
                crate::error::HasKind::kind(&error),
                crate::error::ErrorKind::Usage
            );
            error.to_string()
        };
        let none = refused(Roles::default());
        assert!(
            none.contains("--camera KEY") && none.contains("observation.images.wrist"),
            "{none}"
        );
        let missing = refused(roles("nothing", None));
        assert!(missing.contains("not an image feature"), "{missing}");
        let grey = refused(roles("observation.images.depth", None));
        assert!(grey.contains("3 channels (RGB)"), "{grey}");
        let colour = refused(roles(
            "observation.images.image",
            Some("observation.images.wrist"),
        ));
        assert!(colour.contains("1 channel (depth)"), "{colour}");
        let mut unit = roles("observation.images.image", None);
        unit.depth_unit_m = Some(-1.0);
        assert!(refused(unit).contains("--depth-unit-m"));
    }
}
