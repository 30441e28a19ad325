//! A frame's point cloud: each pixel with depth back-projected ([`back_project`]), cropped,
//! thinned on a voxel grid ([`candidates`]) and sampled by farthest point sampling
//! ([`farthest_point_sampling`]) to [`CloudSettings::points`] points ([`frame_cloud`]).

use crate::episode::Aabb;
use crate::episode::{CameraInfo, Step};
use crate::export::dir::RunOptions;
use crate::export::error::ExportError;
use crate::export::info::DatasetInfo;
use serde_json::{Value, json};

/// How clouds are made.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CloudOptions {
    /// Points per cloud (DP3 uses 1024 or 512).
    pub points: usize,
    /// Points outside this box are dropped (default: the robot's workspace with 20 mm margins).
    pub crop: Aabb,
    /// Edge of the pre-downsampling voxel grid.
    pub voxel_m: f64,
}

impl CloudOptions {
    /// 1024 points, 3 mm voxels, cropped to `crop`.
    pub fn new(crop: Aabb) -> Self {
        CloudOptions {
            points: 1024,
            crop,
            voxel_m: 0.003,
        }
    }
}

/// Cloud settings as a user gives them: the crop box may be left to the dataset's workspace.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CloudSettings {
    /// Points per cloud.
    pub points: usize,
    /// The crop box; None: the dataset's tip workspace grown by `margin_m`.
    pub crop: Option<Aabb>,
    pub margin_m: f64,
    pub voxel_m: f64,
}

impl Default for CloudSettings {
    /// 1024 points, the workspace with 20 mm margins, 3 mm voxels.
    fn default() -> Self {
        CloudSettings {
            points: 1024,
            crop: None,
            margin_m: 0.02,
            voxel_m: 0.003,
        }
    }
}

impl CloudSettings {
    /// The options for clouds of `info`'s frames; refuses a dataset without depth, one without a
    /// recorded workspace when no box is given, and a point count of 0.
    pub fn options(&self, info: &DatasetInfo) -> Result<CloudOptions, ExportError> {
        if self.points == 0 {
            return Err(ExportError::InvalidOptions(
                "a point cloud needs at least one point".into(),
            ));
        }
        if !info.has(crate::episode::FeatureKind::Depth) {
            return Err(ExportError::InvalidOptions(
                "point clouds need the depth image, which this dataset does not have (convert --depth KEY names another tool's)".into(),
            ));
        }
        if !(info.camera.fx_px > 0.0 && info.camera.fy_px > 0.0) {
            return Err(ExportError::InvalidOptions(
                "point clouds need the camera's intrinsics, which this dataset does not record (convert --intrinsics FX,FY,CX,CY gives them)".into(),
            ));
        }
        let crop = match (self.crop, info.tip_workspace) {
            (Some(crop), _) => crop,
            (None, Some(workspace)) => workspace.grown(self.margin_m),
            (None, None) => {
                return Err(ExportError::NoCropBox);
            }
        };
        Ok(CloudOptions {
            points: self.points,
            crop,
            voxel_m: self.voxel_m,
        })
    }

    /// What these settings change in the bytes, by option name.
    pub fn run_options(&self) -> RunOptions {
        RunOptions::recorded(&self.recorded())
    }

    /// The settings as a dataset's options record them.
    pub fn recorded(&self) -> RecordedCloud {
        RecordedCloud {
            cloud_points: self.points,
            cloud_crop_m: self.crop,
            cloud_margin_m: self.margin_m,
            cloud_voxel_m: self.voxel_m,
        }
    }

    /// The settings as a dataset records them (the crop box resolved).
    pub fn describe(&self, info: &DatasetInfo) -> Result<Value, ExportError> {
        let options = self.options(info)?;
        Ok(json!({
            "points": options.points,
            "frame": "world",
            "unit": "m",
            "crop_m": {"min": options.crop.min_m, "max": options.crop.max_m},
            "voxel_m": options.voxel_m,
            "sampling": "crop, one point per voxel (first in pixel order), farthest point sampling from the first; zero-padded",
        }))
    }
}

/// The point-cloud settings a dataset's options record (PLY, PCD, zarr and MCAP datasets).
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct RecordedCloud {
    pub cloud_points: usize,
    /// Null: the dataset's tool-tip workspace with margins.
    pub cloud_crop_m: Option<Aabb>,
    pub cloud_margin_m: f64,
    pub cloud_voxel_m: f64,
}

/// A sampled cloud: exactly `points` entries, the first `valid` real, the rest zero padding.
#[derive(Clone, Debug, PartialEq)]
pub struct Cloud {
    /// World frame, metres.
    pub xyz_m: Vec<[f32; 3]>,
    pub rgb: Vec<[u8; 3]>,
    /// Mask id of each point (empty when the step has no mask).
    pub mask: Vec<u8>,
    pub valid: usize,
}

/// The world position of pixel (u, v) at depth `z_m` along the optical axis.
pub fn back_project(camera: &CameraInfo, u: usize, v: usize, z_m: f64) -> [f64; 3] {
    let x = (u as f64 + 0.5 - camera.cx_px) * z_m / camera.fx_px;
    let y = (v as f64 + 0.5 - camera.cy_px) * z_m / camera.fy_px;
    let m = &camera.world_from_camera;
    let mut out = [0.0; 3];
    for (r, value) in out.iter_mut().enumerate() {
        *value = m[r][0] * x + m[r][1] * y + m[r][2] * z_m + m[r][3];
    }
    out
}

/// The cropped, voxel-downsampled candidates of a frame: (pixel index, world position), one per
/// occupied voxel, in pixel order.
pub fn candidates(
    camera: &CameraInfo,
    depth_m: &[f32],
    options: &CloudOptions,
) -> Vec<(usize, [f64; 3])> {
    let width = camera.width_px as usize;
    let crop = options.crop;
    let voxel = options.voxel_m.max(1e-6);
    let cells: [usize; 3] =
        std::array::from_fn(|i| ((crop.max_m[i] - crop.min_m[i]) / voxel).ceil().max(1.0) as usize);
    let mut taken = Voxels::new(cells);
    let mut out = Vec::new();
    for (pixel, &z) in depth_m.iter().enumerate() {
        if !(z.is_finite() && z > 0.0) {
            continue;
        }
        let p = back_project(camera, pixel % width, pixel / width, f64::from(z));
        if !crop.contains(p) {
            continue;
        }
        let cell: [usize; 3] =
            std::array::from_fn(|i| (((p[i] - crop.min_m[i]) / voxel) as usize).min(cells[i] - 1));
        if taken.take(cell) {
            out.push((pixel, p));
        }
    }
    out
}

/// Grids with more voxels than this keep the occupied ones in a set, not a bitmap (a crop box
/// of metres at millimetre voxels would be terabytes).
const MAX_DENSE_VOXELS: usize = 1 << 22;

/// The occupied voxels of a grid of `cells`.
enum Voxels {
    Dense { cells: [usize; 3], taken: Vec<bool> },
    Sparse(std::collections::HashSet<[usize; 3]>),
}

impl Voxels {
    fn new(cells: [usize; 3]) -> Self {
        let count = cells[0]
            .checked_mul(cells[1])
            .and_then(|n| n.checked_mul(cells[2]));
        match count {
            Some(count) if count <= MAX_DENSE_VOXELS => Voxels::Dense {
                cells,
                taken: vec![false; count],
            },
            _ => Voxels::Sparse(std::collections::HashSet::new()),
        }
    }

    /// Marks `cell` occupied; whether it was free.
    fn take(&mut self, cell: [usize; 3]) -> bool {
        match self {
            Voxels::Dense { cells, taken } => {
                let key = (cell[2] * cells[1] + cell[1]) * cells[0] + cell[0];
                !std::mem::replace(&mut taken[key], true)
            }
            Voxels::Sparse(taken) => taken.insert(cell),
        }
    }
}

/// Farthest point sampling: `count` indices into `points` (all of them if fewer), starting
/// from the first point, each next one the farthest from those chosen (ties: the lowest index).
pub fn farthest_point_sampling(points: &[[f32; 3]], count: usize) -> Vec<usize> {
    if points.is_empty() || count == 0 {
        return Vec::new();
    }
    let count = count.min(points.len());
    let mut nearest = vec![f32::INFINITY; points.len()];
    let mut chosen = Vec::with_capacity(count);
    let mut current = 0;
    for _ in 0..count {
        chosen.push(current);
        let c = points[current];
        let mut best = (f32::NEG_INFINITY, 0);
        for (i, (p, d)) in points.iter().zip(nearest.iter_mut()).enumerate() {
            let dx = p[0] - c[0];
            let dy = p[1] - c[1];
            let dz = p[2] - c[2];
            let distance = dx * dx + dy * dy + dz * dz;
            if distance < *d {
                *d = distance;
            }
            if *d > best.0 {
                best = (*d, i);
            }
        }
        current = best.1;
    }
    chosen
}

/// The cloud of one step (its depth, RGB and, when present, mask).
pub fn frame_cloud(camera: &CameraInfo, step: &Step, options: &CloudOptions) -> Cloud {
    let candidates = candidates(camera, &step.depth_m, options);
    let xyz: Vec<[f32; 3]> = candidates
        .iter()
        .map(|(_, p)| p.map(|v| v as f32))
        .collect();
    let picked = farthest_point_sampling(&xyz, options.points);
    let n = options.points;
    let mut cloud = Cloud {
        xyz_m: vec![[0.0; 3]; n],
        rgb: vec![[0; 3]; n],
        mask: if step.mask.is_empty() {
            Vec::new()
        } else {
            vec![0; n]
        },
        valid: picked.len(),
    };
    for (slot, &i) in picked.iter().enumerate() {
        let pixel = candidates[i].0;
        cloud.xyz_m[slot] = xyz[i];
        if let Some(rgb) = step.rgb.get(pixel * 3..pixel * 3 + 3) {
            cloud.rgb[slot] = [rgb[0], rgb[1], rgb[2]];
        }
        if let Some(id) = step.mask.get(pixel) {
            cloud.mask[slot] = *id;
        }
    }
    cloud
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;

    /// A camera 0.2 m above the origin looking straight down (optical z = world -z).
    fn camera(width: u32, height: u32) -> CameraInfo {
        CameraInfo {
            width_px: width,
            height_px: height,
            fx_px: 100.0,
            fy_px: 100.0,
            cx_px: f64::from(width) / 2.0,
            cy_px: f64::from(height) / 2.0,
            near_m: 0.01,
            far_m: 1.0,
            world_from_camera: [
                [1.0, 0.0, 0.0, 0.0],
                [0.0, -1.0, 0.0, 0.0],
                [0.0, 0.0, -1.0, 0.2],
                [0.0, 0.0, 0.0, 1.0],
            ],
        }
    }

    fn step(width: usize, height: usize, depth: impl Fn(usize, usize) -> f32) -> Step {
        let pixels = width * height;
        Step {
            rgb: (0..pixels * 3).map(|i| (i % 251) as u8).collect(),
            depth_m: (0..pixels).map(|i| depth(i % width, i / width)).collect(),
            mask: (0..pixels).map(|i| (i % 7) as u8).collect(),
            state: [0.0; 7],
            action: [0.0; 7],
            environment_state: [0.0; crate::episode::MAX_OBJECTS * crate::episode::POSE_VALUES],
            extras: Default::default(),
            other: Vec::new(),
        }
    }

    fn everywhere() -> Aabb {
        Aabb {
            min_m: [-1.0; 3],
            max_m: [1.0; 3],
        }
    }

    #[test]
    fn pixels_back_project_onto_the_plane_they_see() {
        let camera = camera(64, 48);
        let p = back_project(&camera, 31, 23, 0.2);
        // Pixel centre (31.5, 23.5) is 0.5 px left of and above the principal point.
        assert!((p[0] - (-0.5 * 0.2 / 100.0)).abs() < 1e-12, "{p:?}");
        assert!((p[1] - (0.5 * 0.2 / 100.0)).abs() < 1e-12, "{p:?}");
        assert!(p[2].abs() < 1e-12, "a floor at z = 0: {p:?}");
    }

    #[test]
    fn a_crop_box_of_more_voxels_than_memory_holds_is_thinned_as_a_small_one() {
        // Kilometres at 3 mm would be 10^19 voxels: a set of the occupied ones, the same
        // candidates as the bitmap of a box that fits.
        let camera = camera(64, 48);
        let frame = step(64, 48, |u, v| 0.15 + 0.0007 * (u + v) as f32);
        let small = CloudOptions::new(everywhere());
        let mut huge = small;
        huge.crop.min_m = huge.crop.min_m.map(|v| v - 1000.0 * 0.003);
        huge.crop.max_m = [1e4; 3];
        assert!(matches!(Voxels::new([1 << 30; 3]), Voxels::Sparse(_)));
        let (a, b) = (
            candidates(&camera, &frame.depth_m, &small),
            candidates(&camera, &frame.depth_m, &huge),
        );
        assert!(a.len() > 100, "{}", a.len());
        assert_eq!(
            a.iter().map(|c| c.0).collect::<Vec<_>>(),
            b.iter().map(|c| c.0).collect::<Vec<_>>()
        );
    }

    #[test]
    fn clouds_are_cropped_sampled_padded_and_coloured_from_their_pixel() {
        let camera = camera(64, 48);
        // A floor at z = 0 with a box 5 cm tall over the left half.
        let frame = step(64, 48, |u, _| if u < 32 { 0.15 } else { 0.2 });
        let mut options = CloudOptions::new(everywhere());
        options.points = 256;
        let cloud = frame_cloud(&camera, &frame, &options);
        assert_eq!(cloud.xyz_m.len(), 256);
        assert_eq!(cloud.valid, 256);
        let heights: std::collections::BTreeSet<i32> = cloud
            .xyz_m
            .iter()
            .map(|p| (p[2] * 1000.0).round() as i32)
            .collect();
        assert_eq!(
            heights,
            [0, 50].into_iter().collect(),
            "both surfaces sampled"
        );
        // Every point's colour and mask are its own pixel's.
        let candidates = candidates(&camera, &frame.depth_m, &options);
        for slot in 0..cloud.valid {
            let (pixel, _) = candidates
                .iter()
                .find(|(_, p)| p.map(|v| v as f32) == cloud.xyz_m[slot])
                .expect("a candidate");
            assert_eq!(cloud.mask[slot], frame.mask[*pixel]);
            assert_eq!(cloud.rgb[slot][0], frame.rgb[pixel * 3]);
        }
        // Crop to the box's top: only its points survive, and the rest is zero padding.
        options.crop = Aabb {
            min_m: [-1.0, -1.0, 0.04],
            max_m: [1.0, 1.0, 1.0],
        };
        options.points = 4096;
        let cropped = frame_cloud(&camera, &frame, &options);
        assert!(cropped.valid > 0 && cropped.valid < 4096);
        assert!(cropped.xyz_m[..cropped.valid].iter().all(|p| p[2] > 0.04));
        assert!(
            cropped.xyz_m[cropped.valid..]
                .iter()
                .all(|p| *p == [0.0; 3])
        );
        // No depth: an all-padding cloud.
        let empty = frame_cloud(&camera, &step(64, 48, |_, _| 0.0), &options);
        assert_eq!(empty.valid, 0);
    }

    #[test]
    fn farthest_point_sampling_spreads_out_and_is_deterministic() {
        let mut rng = SplitMix64::new(7);
        let points: Vec<[f32; 3]> = (0..500)
            .map(|_| [rng.next_f64() as f32, rng.next_f64() as f32, 0.0])
            .collect();
        let picked = farthest_point_sampling(&points, 4);
        assert_eq!(picked, farthest_point_sampling(&points, 4));
        assert_eq!(picked[0], 0);
        // The second is the farthest from the first.
        let d = |a: [f32; 3], b: [f32; 3]| (0..3).map(|i| (a[i] - b[i]).powi(2)).sum::<f32>();
        let farthest = (0..points.len())
            .max_by(|&a, &b| d(points[a], points[0]).total_cmp(&d(points[b], points[0])))
            .expect("points");
        assert_eq!(picked[1], farthest);
        // Sampled points are farther apart than random ones.
        let spread = |ids: &[usize]| {
            let mut min = f32::INFINITY;
            for (k, &a) in ids.iter().enumerate() {
                for &b in &ids[k + 1..] {
                    min = min.min(d(points[a], points[b]));
                }
            }
            min
        };
        let fps = farthest_point_sampling(&points, 32);
        let first: Vec<usize> = (0..32).collect();
        assert!(spread(&fps) > 4.0 * spread(&first));
        assert_eq!(farthest_point_sampling(&points[..3], 10).len(), 3);
    }
}
