//! The renderer: exact depth, back-projection, projected areas, occlusion, near-plane clipping,
//! watertight meshes, pixel alignment of RGB, depth and mask, and golden checksums.

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use surgvla::assets::{Appearance, MaskClass, SceneAssets};
use surgvla::collect::Fnv64;
use surgvla::render::raster::pixel_point;
use surgvla::render::{Camera, Frame, Instance, Material, Mesh, RenderOptions, Renderer};
use surgvla::sim::{SimConfig, Simulator};
use surgvla::task::TaskId;

/// A 224 x 224, 60 deg camera at the world origin looking along +z (world = optical frame).
fn camera() -> Camera {
    Camera::from_fov(
        224,
        224,
        60f64.to_radians(),
        0.004,
        0.5,
        Isometry3::identity(),
    )
}

fn instance(mesh: &Mesh, pose: Isometry3<f64>, mask_id: u8, cull: bool) -> Instance<'_> {
    Instance {
        mesh,
        world_from_mesh: pose,
        material: Material::matte([200, 100, 50]),
        mask_id,
        cull_back_faces: cull,
    }
}

fn render(instances: &[Instance<'_>]) -> Frame {
    Renderer::new(RenderOptions::default()).render(&camera(), instances)
}

/// A square of side `2 * half` in the z = 0 plane, split into `n x n` cells of 2 triangles.
fn square(half: f32, n: usize) -> Mesh {
    let mut mesh = Mesh::slab([half, half, 0.0], n, n, |_, _| 0.0);
    // Keep only the top grid (the slab's first 2 n^2 triangles).
    mesh.triangles.truncate(2 * n * n);
    mesh
}

fn at(x: f64, y: f64, z: f64) -> Isometry3<f64> {
    Isometry3::translation(x, y, z)
}

#[test]
fn a_plane_at_known_distance_has_exact_depth_everywhere() {
    let plane = square(1.0, 1);
    for z in [0.05, 0.137, 0.3] {
        let frame = render(&[instance(&plane, at(0.0, 0.0, z), 7, false)]);
        for (i, depth) in frame.depth_m.iter().enumerate() {
            assert!(
                (f64::from(*depth) - z).abs() < 1e-6 * z,
                "pixel {i}: {depth} vs {z}"
            );
        }
        assert!(frame.mask.iter().all(|m| *m == 7));
    }
}

#[test]
fn back_projected_sphere_pixels_lie_on_the_sphere() {
    let radius = 0.02;
    let centre = Vector3::new(0.01, -0.005, 0.12);
    let sphere = Mesh::sphere(radius as f32, 64, 128);
    let frame = render(&[instance(&sphere, at(centre.x, centre.y, centre.z), 3, true)]);
    let mut worst = 0.0f64;
    let mut count = 0;
    for v in 0..frame.height_px {
        for u in 0..frame.width_px {
            if frame.mask[(v * frame.width_px + u) as usize] != 3 {
                continue;
            }
            let p = pixel_point(&camera(), &frame, u, v).expect("sphere pixel has depth");
            worst = worst.max(((p.coords - centre).norm() - radius).abs());
            count += 1;
        }
    }
    assert!(count > 1000, "{count} pixels");
    assert!(worst < 5e-4, "worst distance from the sphere {worst} m");
}

#[test]
fn mask_pixel_count_matches_projected_area() {
    // A 40 mm square facing the camera at z: (f * 0.04 / z)^2 pixels.
    let cam = camera();
    let plane = square(0.02, 4);
    for (x, z) in [(0.0, 0.1), (0.013, 0.1), (-0.02, 0.15)] {
        let frame = render(&[instance(&plane, at(x, 0.0031, z), 9, false)]);
        let counted = frame.mask.iter().filter(|m| **m == 9).count() as f64;
        let expected = (cam.fx_px * 0.04 / z).powi(2);
        assert!(
            (counted - expected).abs() < 0.03 * expected,
            "{counted} vs {expected}"
        );
    }
}

#[test]
fn an_object_behind_another_is_hidden() {
    let near = square(0.01, 1);
    let far = square(0.05, 1);
    // Draw order must not matter.
    for order in [0, 1] {
        let a = instance(&near, at(0.0, 0.0, 0.1), 1, false);
        let b = instance(&far, at(0.0, 0.0, 0.2), 2, false);
        let frame = if order == 0 {
            render(&[a, b])
        } else {
            render(&[b, a])
        };
        let centre = 112 * 224 + 112;
        assert_eq!(frame.mask[centre], 1);
        assert!((frame.depth_m[centre] - 0.1).abs() < 1e-6);
        let outside = 112 * 224 + 150;
        assert_eq!(frame.mask[outside], 2);
        assert!((frame.depth_m[outside] - 0.2).abs() < 1e-6);
    }
}

#[test]
fn triangles_crossing_the_near_plane_are_clipped_not_dropped() {
    // A floor below the camera running from behind it to far ahead, made of two big triangles:
    // both cross z = 4 mm.
    let floor = Mesh::cuboid([0.3, 0.0005, 0.3]);
    let frame = render(&[instance(&floor, at(0.0, 0.02, 0.1), 5, false)]);
    let bottom_row = &frame.mask[223 * 224..];
    assert!(
        bottom_row.iter().all(|m| *m == 5),
        "the floor reaches the bottom of the image"
    );
    // The bottom centre pixel's ray meets the floor's top (y = 0.0195) at z = 0.0195 / tan.
    let tan = (223.5 - 112.0) / camera().fy_px;
    let expected = 0.0195 / tan;
    let near = f64::from(frame.depth_m[223 * 224 + 112]);
    assert!(
        (near - expected).abs() < 1e-5,
        "bottom centre depth {near}, expected {expected}"
    );
}

#[test]
fn subdivided_meshes_are_watertight() {
    // A finely split square in front of a background plane: any crack shows the background.
    let fine = square(0.03, 37);
    let back = square(1.0, 1);
    let tilt = Isometry3::from_parts(
        Translation3::new(0.001, -0.002, 0.1),
        UnitQuaternion::from_euler_angles(0.4, -0.3, 0.7),
    );
    let frame = render(&[
        instance(&fine, tilt, 1, false),
        instance(&back, at(0.0, 0.0, 0.3), 2, false),
    ]);
    let cam = camera();
    let local_origin = tilt.inverse() * Point3::origin();
    let mut inside = 0;
    for v in 0..224u32 {
        for u in 0..224u32 {
            // Pixels whose centre ray hits the square's interior (1 % margin from its edges).
            let ray = cam.back_project(u, v, 1.0).coords;
            let local_dir = tilt.rotation.inverse() * ray;
            let t = -local_origin.z / local_dir.z;
            let hit = local_origin.coords + local_dir * t;
            if t > 0.0 && hit.x.abs() < 0.0297 && hit.y.abs() < 0.0297 {
                inside += 1;
                assert_eq!(
                    frame.mask[(v * 224 + u) as usize],
                    1,
                    "crack at pixel ({u}, {v})"
                );
            }
        }
    }
    assert!(inside > 5000, "{inside}");
}

fn task_frame(task: TaskId, seed: u64, steps: u32, supersample: u32) -> Frame {
    let scene = task.scene(seed).unwrap();
    let mut sim = Simulator::new(SimConfig::default(), scene.clone());
    let mut policy = surgvla::collect::demo_plan(&sim);
    surgvla::collect::rollout(&mut sim, &mut policy, steps);
    let assets = SceneAssets::new(&scene, seed, Appearance::default());
    let mut renderer = Renderer::new(RenderOptions {
        supersample,
        ..RenderOptions::default()
    });
    surgvla::view::render_simulator(&assets, &mut renderer, &Camera::endoscope(), &sim)
}

#[test]
fn rgb_depth_and_mask_line_up_pixel_for_pixel() {
    let frame = task_frame(TaskId::GauzePickDistractors, 3, 0, 1);
    let background = Renderer::default().options.lighting.background;
    let background_rgb = background.map(surgvla::render::material::linear_to_srgb);
    for i in 0..frame.mask.len() {
        let rgb = &frame.rgb[i * 3..i * 3 + 3];
        if frame.mask[i] == MaskClass::Background.id() {
            assert_eq!(frame.depth_m[i], 0.0);
            assert_eq!(rgb, background_rgb);
        } else {
            assert!(frame.depth_m[i] > 0.0);
        }
    }
    for class in [
        MaskClass::Tray,
        MaskClass::Gauze,
        MaskClass::DistractorNeedle,
        MaskClass::InstrumentShaft,
        MaskClass::InstrumentJaws,
    ] {
        assert!(frame.mask.contains(&class.id()), "{class:?} not visible");
    }
    // Supersampling changes RGB only.
    let smooth = task_frame(TaskId::GauzePickDistractors, 3, 0, 2);
    assert_eq!(smooth.depth_m, frame.depth_m);
    assert_eq!(smooth.mask, frame.mask);
    assert_ne!(smooth.rgb, frame.rgb);
}

#[test]
fn the_gauze_appears_where_the_reference_frame_shows_it() {
    // Reference frame: the gauze near the image centre, about 25 px wide.
    let frame = task_frame(TaskId::GauzePick, 0, 0, 1);
    let gauze: Vec<(usize, usize)> = (0..224 * 224)
        .filter(|i| frame.mask[*i] == MaskClass::Gauze.id())
        .map(|i| (i % 224, i / 224))
        .collect();
    let min_u = gauze.iter().map(|p| p.0).min().unwrap_or(0);
    let max_u = gauze.iter().map(|p| p.0).max().unwrap_or(0);
    let mean_v = gauze.iter().map(|p| p.1 as f64).sum::<f64>() / gauze.len().max(1) as f64;
    assert!(
        (20..=40).contains(&(max_u - min_u)),
        "gauze {} px wide",
        max_u - min_u
    );
    assert!((90.0..150.0).contains(&mean_v), "gauze centre row {mean_v}");
}

fn digest(frame: &Frame) -> u64 {
    let mut h = Fnv64::default();
    frame.rgb.iter().for_each(|b| h.write_u64(u64::from(*b)));
    frame
        .depth_m
        .iter()
        .for_each(|d| h.write_u64(u64::from(d.to_bits())));
    frame.mask.iter().for_each(|m| h.write_u64(u64::from(*m)));
    h.finish()
}

/// Golden checksums of fixed renders. After an intended visual change, regenerate with
/// `SURGVLA_BLESS=1 cargo test --release --test all render::golden` and commit the file.
#[test]
fn golden() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/golden/render.txt");
    let cases = [
        (TaskId::GauzePick, 1, 0),
        (TaskId::NeedlePick, 2, 14),
        (TaskId::Electrocoagulation, 3, 0),
        (TaskId::VesselClipping, 4, 0),
        (TaskId::Hemostasis, 5, 0),
    ];
    let actual: String = cases
        .iter()
        .map(|(task, seed, steps)| {
            let frame = task_frame(*task, *seed, *steps, 2);
            format!(
                "{} seed {seed} steps {steps}: {:016x}\n",
                task.code(),
                digest(&frame)
            )
        })
        .collect();
    if std::env::var_os("SURGVLA_BLESS").is_some() {
        std::fs::write(&path, &actual).expect("write golden file");
    }
    let expected =
        std::fs::read_to_string(&path).expect("tests/golden/render.txt (bless it first)");
    assert_eq!(
        actual, expected,
        "renders changed; if intended, re-bless (see the test's doc)"
    );
}

#[test]
fn organ_shapes_follow_the_seed() {
    let a = task_frame(TaskId::Electrocoagulation, 10, 0, 1);
    let b = task_frame(TaskId::Electrocoagulation, 10, 0, 1);
    let c = task_frame(TaskId::Electrocoagulation, 11, 0, 1);
    assert_eq!(a, b);
    assert_ne!(a.mask, c.mask);
    assert!(
        a.mask.contains(&MaskClass::Kidney.id()) && a.mask.contains(&MaskClass::TargetMark.id())
    );
}

#[test]
fn randomized_appearance_changes_colours_not_geometry() {
    let scene = TaskId::Hemostasis.scene(5).unwrap();
    let sim = Simulator::new(SimConfig::default(), scene.clone());
    let render_with = |appearance: Appearance| {
        let assets = SceneAssets::new(&scene, 5, appearance);
        let options = RenderOptions {
            lighting: appearance.lighting(Default::default()),
            supersample: 1,
            mask: true,
        };
        surgvla::view::render_simulator(
            &assets,
            &mut Renderer::new(options),
            &Camera::endoscope(),
            &sim,
        )
    };
    let plain = render_with(Appearance::default());
    let varied = render_with(Appearance::randomized(5));
    assert_eq!(plain.mask, varied.mask);
    assert_eq!(plain.depth_m, varied.depth_m);
    assert_ne!(plain.rgb, varied.rgb);
    assert_ne!(Appearance::randomized(5), Appearance::randomized(6));
}

#[test]
fn per_pixel_lighting_changes_only_the_gouraud_surfaces() {
    let scene = TaskId::Electrocoagulation.scene(1).unwrap();
    let sim = Simulator::new(SimConfig::default(), scene.clone());
    let assets = SceneAssets::new(&scene, 1, Appearance::default());
    let render_with = |allow_per_vertex: bool| {
        let lighting = surgvla::render::Lighting {
            allow_per_vertex,
            ..Default::default()
        };
        let mut renderer = Renderer::new(RenderOptions {
            lighting,
            supersample: 1,
            mask: true,
        });
        surgvla::view::render_simulator(&assets, &mut renderer, &Camera::endoscope(), &sim)
    };
    let (fast, exact) = (render_with(true), render_with(false));
    assert_eq!(fast.mask, exact.mask);
    let (mut differing, mut far_off) = (0, 0);
    for i in 0..fast.mask.len() {
        let (a, b) = (&fast.rgb[i * 3..i * 3 + 3], &exact.rgb[i * 3..i * 3 + 3]);
        let gouraud = fast.mask[i] == MaskClass::Tray.id();
        if !gouraud {
            assert_eq!(a, b, "pixel {i} of class {} changed", fast.mask[i]);
        }
        far_off += usize::from(a.iter().zip(b).any(|(x, y)| x.abs_diff(*y) > 16));
        differing += usize::from(a != b);
    }
    assert!(
        differing > 1000,
        "the option must change the Gouraud surfaces ({differing} pixels)"
    );
    // Gouraud only departs visibly at grazing silhouettes.
    assert!(
        far_off * 100 < differing,
        "{far_off} of {differing} changed pixels differ by > 16 levels"
    );
}

#[test]
fn the_needles_thin_wire_is_in_the_depth_image_where_the_mask_has_it() {
    // The wire is 1 mm thick, about 1.3 px at the endoscope's distance: every pixel the mask
    // gives to the needle must carry the wire's depth (back-projected above the pad), not the
    // pad's, and the wire must be continuous (an arc, not a few dots).
    let camera = Camera::endoscope();
    for seed in [2, 5, 9] {
        let frame = task_frame(TaskId::NeedlePick, seed, 0, 1);
        let needle = MaskClass::Needle.id();
        let mut heights = Vec::new();
        for v in 0..frame.height_px {
            for u in 0..frame.width_px {
                if frame.mask[(v * frame.width_px + u) as usize] != needle {
                    continue;
                }
                let optical = pixel_point(&camera, &frame, u, v).expect("depth under the mask");
                let world = camera.world_from_camera * optical;
                heights.push(world.z - surgvla::scene::TRAY_TOP_Z_M);
            }
        }
        assert!(
            heights.len() > 40,
            "seed {seed}: {} wire pixels",
            heights.len()
        );
        for h in &heights {
            assert!(
                (0.0001..=0.0012).contains(h),
                "seed {seed}: a wire pixel back-projects {:.2} mm above the pad",
                h * 1e3
            );
        }
    }
}

/// The static layer kept between frames gives the same pixels, depth and mask as drawing every
/// frame whole, while the instrument and a grasped object move over it; the same renderer given
/// another camera or another scene draws a new layer. So does one that draws into the buffers
/// of frames handed back, without the mask.
#[test]
fn frames_drawn_over_a_kept_static_layer_are_the_frames_drawn_whole() {
    use surgvla::collect::rollout;
    use surgvla::policy::ExpertLibrary;
    use surgvla::task::TaskConfig;
    use surgvla::view::{render_simulator, render_simulator_over_static};
    let library = ExpertLibrary::builtin().expect("plans");
    let mut layered = Renderer::new(RenderOptions::default());
    let mut recycling = Renderer::new(RenderOptions {
        mask: false,
        ..RenderOptions::default()
    });
    let mut compared = 0;
    for (task, seed) in [
        (TaskId::Hemostasis, 3),
        (TaskId::VesselClipping, 4),
        (TaskId::Hemostasis, 5),
    ] {
        let instance = task.instance(seed, &TaskConfig::default()).expect("scene");
        let assets = SceneAssets::new(&instance.scene, seed, Appearance::default());
        let mut sim = Simulator::new(SimConfig::default(), instance.scene.clone());
        let mut expert = library
            .plan(task)
            .expect("plan")
            .expert(&instance, &sim.observation(), seed)
            .expect("expert");
        let commands: Vec<_> = rollout(&mut sim, &mut expert, 45)
            .steps
            .iter()
            .map(|s| s.command)
            .collect();
        let mut wide = Camera::endoscope();
        wide.fx_px *= 0.8;
        wide.fy_px *= 0.8;
        for camera in [Camera::endoscope(), wide] {
            let mut sim = Simulator::new(SimConfig::default(), instance.scene.clone());
            for (i, command) in commands.iter().enumerate() {
                sim.step_native(command);
                if i % 4 != 0 {
                    continue;
                }
                let whole = render_simulator(
                    &assets,
                    &mut Renderer::new(RenderOptions::default()),
                    &camera,
                    &sim,
                );
                let over = render_simulator_over_static(&assets, &mut layered, &camera, &sim);
                assert!(
                    whole == over,
                    "{task} seed {seed} step {i}: the frames differ"
                );
                // Drawn into recycled buffers (whatever they held), without the mask.
                let mut again =
                    render_simulator_over_static(&assets, &mut recycling, &camera, &sim);
                assert!(again.mask.is_empty(), "no mask asked for");
                assert!(
                    again.rgb == whole.rgb && again.depth_m == whole.depth_m,
                    "{task} seed {seed} step {i}: the recycled frame differs"
                );
                again.rgb.fill(7);
                again.depth_m.truncate(5);
                recycling.recycle(again.rgb, again.depth_m, vec![1; 3]);
                compared += 1;
            }
        }
    }
    assert!(compared > 30, "{compared}");
}
