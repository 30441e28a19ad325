//! Point clouds against the simulator's ground truth: every point whose mask id names a movable
//! object lies within 2 mm of that object's true surface (box faces for gauze and block, the wire
//! for the needle), in scenes with every object kind and distractors, before and after the
//! expert moved things.

use nalgebra::{Point3, Vector3};
use surgvla::assets::{Appearance, SceneAssets};
use surgvla::collect::rollout;
use surgvla::episode::{Aabb, MAX_OBJECTS, POSE_VALUES, Step};
use surgvla::error::HasKind as _;
use surgvla::export::pointcloud::{CloudOptions, frame_cloud};
use surgvla::policy::ExpertLibrary;
use surgvla::render::{Camera, RenderOptions, Renderer};
use surgvla::scene::{
    BLOCK_HALF_EXTENTS_M, GAUZE_HALF_EXTENTS_M, NEEDLE_SEGMENTS, NEEDLE_WIRE_RADIUS_M, ObjectKind,
    needle_arc_points,
};
use surgvla::sim::{SimConfig, Simulator};
use surgvla::task::{TaskConfig, TaskId};
use surgvla::view::{camera_info, render_simulator};

/// Distance from `p` (object frame) to the surface of a box of half extents `h`.
fn box_surface_distance(p: Vector3<f64>, h: [f64; 3]) -> f64 {
    let q = Vector3::new(p.x.abs() - h[0], p.y.abs() - h[1], p.z.abs() - h[2]);
    let outside = Vector3::new(q.x.max(0.0), q.y.max(0.0), q.z.max(0.0)).norm();
    let inside = q.x.max(q.y).max(q.z).min(0.0);
    (outside + inside).abs()
}

/// Distance from `p` (object frame) to the needle's wire surface.
fn needle_surface_distance(p: Vector3<f64>) -> f64 {
    let arc = needle_arc_points(NEEDLE_SEGMENTS * 4);
    let to_line = arc
        .windows(2)
        .map(|w| {
            let (a, b) = (w[0], w[1]);
            let t = ((p - a).dot(&(b - a)) / (b - a).norm_squared()).clamp(0.0, 1.0);
            (p - (a + (b - a) * t)).norm()
        })
        .fold(f64::INFINITY, f64::min);
    (to_line - NEEDLE_WIRE_RADIUS_M).abs()
}

#[test]
fn points_labelled_as_an_object_lie_on_its_true_surface() {
    let library = ExpertLibrary::builtin().expect("plans");
    let camera = Camera::endoscope();
    let info = camera_info(&camera);
    let workspace = surgvla::sim::control::Workspace::reference();
    let crop = Aabb {
        min_m: workspace.min_m,
        max_m: workspace.max_m,
    }
    .grown(0.02);
    let options = CloudOptions {
        points: 4096,
        ..CloudOptions::new(crop)
    };
    let config = TaskConfig {
        distractors: 3,
        ..TaskConfig::default()
    };
    let mut checked = std::collections::BTreeMap::new();
    for (task, seed, steps) in [
        (TaskId::PickAndPlace, 3, 0),
        (TaskId::PickAndPlace, 3, 30),
        (TaskId::GauzePickDistractors, 5, 0),
        (TaskId::NeedlePickDistractors, 7, 0),
        (TaskId::NeedlePickDistractors, 7, 25),
    ] {
        let instance = task.instance(seed, &config).expect("instance");
        let mut sim = Simulator::new(SimConfig::default(), instance.scene.clone());
        if steps > 0 {
            let mut policy = library
                .plan(task)
                .expect("plan")
                .expert(&instance, &sim.observation(), seed)
                .expect("expert");
            rollout(&mut sim, &mut policy, steps);
        }
        let assets = SceneAssets::new(&instance.scene, seed, Appearance::default());
        let mut renderer = Renderer::new(RenderOptions::default());
        let frame = render_simulator(&assets, &mut renderer, &camera, &sim);
        let step = Step {
            rgb: frame.rgb,
            depth_m: frame.depth_m,
            mask: frame.mask,
            state: [0.0; 7],
            action: [0.0; 7],
            environment_state: [0.0; MAX_OBJECTS * POSE_VALUES],
            extras: Default::default(),
            other: Vec::new(),
        };
        let cloud = frame_cloud(&info, &step, &options);
        let poses = sim.object_poses();
        for i in 0..cloud.valid {
            let id = cloud.mask[i];
            let (kind, distractor) = match id {
                6 => (ObjectKind::Gauze, false),
                7 => (ObjectKind::Needle, false),
                8 => (ObjectKind::Block, false),
                16 => (ObjectKind::Gauze, true),
                17 => (ObjectKind::Needle, true),
                18 => (ObjectKind::Block, true),
                _ => continue,
            };
            let [x, y, z] = cloud.xyz_m[i].map(f64::from);
            let point = Point3::new(x, y, z);
            // The nearest object of the labelled class (distractors share an id).
            let distance = sim
                .scene()
                .objects
                .iter()
                .zip(&poses)
                .filter(|(o, _)| o.kind == kind && o.distractor == distractor)
                .map(|(_, pose)| {
                    let local = pose.inverse_transform_point(&point).coords;
                    match kind {
                        ObjectKind::Gauze => box_surface_distance(local, GAUZE_HALF_EXTENTS_M),
                        ObjectKind::Block => box_surface_distance(local, BLOCK_HALF_EXTENTS_M),
                        ObjectKind::Needle => needle_surface_distance(local),
                    }
                })
                .fold(f64::INFINITY, f64::min);
            assert!(
                distance <= 0.002,
                "{} seed {seed} step {steps}: a point labelled {id} is {:.2} mm from its object",
                task.code(),
                distance * 1e3
            );
            *checked.entry(id).or_insert(0) += 1;
        }
    }
    // Every object class was seen and checked, the distractors included.
    for id in [6, 7, 8, 16, 17, 18] {
        assert!(
            checked.get(&id).copied().unwrap_or(0) >= 5,
            "mask id {id}: {checked:?}"
        );
    }
}

#[test]
fn cloud_formats_refuse_a_dataset_without_depth_or_workspace_before_writing() {
    use surgvla::export::open_sink;
    use surgvla::export::pointcloud::files::CloudFileFormat;
    use surgvla::export::pointcloud::{CloudFileOptions, CloudSettings};
    use surgvla::export::zarr::ZarrOptions;
    let mut info = crate::util::info(false);
    let out = crate::util::temp_root("clouds-refused");
    info.features
        .retain(|f| f.kind != surgvla::episode::FeatureKind::Depth);
    let ply = CloudFileOptions {
        format: CloudFileFormat::Ply,
        settings: CloudSettings::default(),
    };
    let error = open_sink(&out, &info, &ply, false).err().expect("no depth");
    assert!(error.to_string().contains("depth"), "{error}");
    assert_eq!(error.kind(), surgvla::error::ErrorKind::Usage);
    // A zarr store without depth has no clouds: Diffusion Policy's images, state and action.
    let zarr = ZarrOptions::default();
    let mut sink = open_sink(&out, &info, &zarr, false).expect("a store without clouds");
    sink.finish().expect("finished");
    for (array, present) in [("point_cloud", false), ("img", true), ("state", true)] {
        assert_eq!(
            out.join("data").join(array).join(".zarray").is_file(),
            present,
            "{array}"
        );
    }
    let out = crate::util::temp_root("clouds-refused-2");
    let mut info = crate::util::info(false);
    info.tip_workspace = None;
    let error = open_sink(&out, &info, &zarr, false)
        .err()
        .expect("no workspace");
    assert!(error.to_string().contains("crop box"), "{error}");
    let given = ZarrOptions {
        cloud: CloudSettings {
            crop: Some(Aabb {
                min_m: [0.4, -0.1, 0.6],
                max_m: [0.7, 0.1, 0.8],
            }),
            ..CloudSettings::default()
        },
        ..ZarrOptions::default()
    };
    assert!(!out.exists(), "nothing written before the refusal");
    assert!(
        open_sink(&out, &info, &given, false).is_ok(),
        "a given box will do"
    );
}

#[test]
fn record_writes_one_mcap_and_refuses_to_overwrite_it() {
    let dir = crate::util::temp_root("record");
    std::fs::create_dir_all(&*dir).expect("dir");
    let out = dir.join("ep.mcap");
    let out_text = out.display().to_string();
    let args = [
        "record", "--task", "T1-1", "--seed", "2", "--out", &out_text,
    ];
    let (code, stdout, stderr) = crate::util::surgvla(&args);
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stdout.contains("success") && stdout.contains("ep.mcap"),
        "{stdout}"
    );
    let bytes = std::fs::read(&out).expect("mcap");
    assert_eq!(&bytes[..8], b"\x89MCAP0\r\n", "the MCAP magic");
    // Channel records are not compressed; the messages are (their content: tests/interop/mcap).
    for topic in ["/scene", "/tf", "/endoscope/points"] {
        assert!(
            bytes.windows(topic.len()).any(|w| w == topic.as_bytes()),
            "{topic} is recorded"
        );
    }
    let (code, _, stderr) = crate::util::surgvla(&args);
    assert_eq!(code, 2, "{stderr}");
    assert!(stderr.contains("already exists"), "{stderr}");
    // Same task and seed, same bytes.
    let again = dir.join("again.mcap");
    let again_text = again.display().to_string();
    let (code, _, _) = crate::util::surgvla(&[
        "record",
        "--task",
        "T1-1",
        "--seed",
        "2",
        "--out",
        &again_text,
    ]);
    assert_eq!(code, 0);
    assert!(
        std::fs::read(&again).expect("again") == bytes,
        "deterministic"
    );
}
