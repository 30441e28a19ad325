//! Seeing the simulation: renders a [`Simulator`]'s current state through the procedural assets
//! and the CPU renderer, and lays out contact sheets. This bridge knows the simulator's public
//! state (object poses, instrument pose), never rapier; the renderer below it knows neither.

use crate::assets::{Appearance, SceneAssets};
use crate::chart::{Canvas, GLYPH_PX, fit};
use crate::episode::CameraInfo;
use crate::render::image::{depth_visualisation, mask_colour, mask_visualisation, plasma};
use crate::render::{Camera, Frame, RenderOptions, Renderer};
use crate::scene::InstrumentPose;
use crate::sim::{SimConfig, Simulator};
use crate::task::TaskId;

/// Renders the current state of `sim` as seen by `camera`.
pub fn render_simulator(
    assets: &SceneAssets,
    renderer: &mut Renderer,
    camera: &Camera,
    sim: &Simulator,
) -> Frame {
    let instances = assets.instances(
        &sim.object_poses(),
        &sim.instrument_pose(),
        &sim.world_from_clips(),
    );
    renderer.render(camera, &instances)
}

/// [`render_simulator`] with a renderer that keeps the scene's static layer from frame to
/// frame (the same pixels, drawn faster): for a renderer serving one scene, e.g. an episode's.
pub fn render_simulator_over_static(
    assets: &SceneAssets,
    renderer: &mut Renderer,
    camera: &Camera,
    sim: &Simulator,
) -> Frame {
    let instances = assets.instances(
        &sim.object_poses(),
        &sim.instrument_pose(),
        &sim.world_from_clips(),
    );
    renderer.render_over_static(camera, &instances, assets.static_count())
}

/// An RGB image assembled from tiles.
#[derive(Clone, Debug, PartialEq)]
pub struct Sheet {
    pub width_px: u32,
    pub height_px: u32,
    pub rgb: Vec<u8>,
}

/// The contact sheet's margins: the row names and the depth scale on the left, the column
/// names on top, pixels.
pub const SHEET_LEFT_PX: u32 = 72;
pub const SHEET_TOP_PX: u32 = 16;
/// Between tiles, pixels.
const SHEET_GAP_PX: u32 = 4;
/// One mask legend entry's width: a swatch and a name.
const LEGEND_ENTRY_PX: usize = 22 * GLYPH_PX;

/// The start frame of every task in `tasks` (one column each, named on top): RGB, depth and
/// mask rows, named on the left. Each depth tile says its range (its colours run from its
/// nearest surface, bright, to its farthest, dark, as the scale on the left shows); under the
/// grid, a legend names the mask's colours.
pub fn contact_sheet(
    tasks: &[TaskId],
    seed: u64,
    options: RenderOptions,
    appearance: Appearance,
) -> Result<Sheet, crate::task::SpawnError> {
    let camera = Camera::endoscope();
    let (w, h) = (camera.width_px, camera.height_px);
    let gap = SHEET_GAP_PX;
    let columns = tasks.len() as u32;
    let mut renderer = Renderer::new(RenderOptions {
        lighting: appearance.lighting(options.lighting),
        ..options
    });
    let mut frames = Vec::with_capacity(tasks.len());
    for task in tasks {
        let scene = task.scene(seed)?;
        let sim = Simulator::new(SimConfig::default(), scene.clone());
        let assets = SceneAssets::new(&scene, seed, appearance);
        frames.push(render_simulator(&assets, &mut renderer, &camera, &sim));
    }
    let mut ids: Vec<u8> = frames.iter().flat_map(|f| f.mask.iter().copied()).collect();
    ids.sort_unstable();
    ids.dedup();
    let grid_w = (columns * (w + gap)).saturating_sub(gap) as usize;
    let width = SHEET_LEFT_PX as usize + grid_w;
    let per_row = (width / LEGEND_ENTRY_PX).max(1);
    let legend_h = 8 + ids.len().div_ceil(per_row) * 14;
    let grid_h = (3 * (h + gap) - gap) as usize;
    let height = SHEET_TOP_PX as usize + grid_h + legend_h;
    let mut canvas = Canvas::new(width, height, [255, 255, 255]);
    let (left, top) = (SHEET_LEFT_PX as usize, SHEET_TOP_PX as usize);
    let (tile_w, tile_h, gap) = (w as usize, h as usize, gap as usize);
    let black = [0, 0, 0];
    for (column, (task, frame)) in tasks.iter().zip(&frames).enumerate() {
        let x = left + column * (tile_w + gap);
        let name = fit(
            &format!("{} {}", task.code(), task.name()),
            tile_w / GLYPH_PX,
        );
        canvas.text(x, 4, &name, 1, black);
        canvas.paste(x, top, tile_w, &frame.rgb);
        let depth_y = top + tile_h + gap;
        canvas.paste(x, depth_y, tile_w, &depth_visualisation(frame));
        let range = depth_range_mm(frame);
        let width = Canvas::text_width(&range, 1);
        let label_y = depth_y + tile_h - GLYPH_PX - 4;
        canvas.fill(
            x + 2,
            label_y - 2,
            x + 6 + width,
            label_y + GLYPH_PX + 2,
            [255; 3],
        );
        canvas.text(x + 4, label_y, &range, 1, black);
        canvas.paste(
            x,
            top + 2 * (tile_h + gap),
            tile_w,
            &mask_visualisation(frame),
        );
    }
    sheet_margin(&mut canvas, (tile_h, gap));
    mask_legend(&mut canvas, &ids, top + grid_h + 8, per_row);
    Ok(Sheet {
        width_px: canvas.width_px as u32,
        height_px: canvas.height_px as u32,
        rgb: canvas.pixels,
    })
}

/// The sheet's left margin: the rows' names, and the depth scale (near, bright, at the top;
/// far, dark, at the bottom, as each tile spreads its own range).
fn sheet_margin(canvas: &mut Canvas, (tile_h, gap): (usize, usize)) {
    let black = [0, 0, 0];
    let top = SHEET_TOP_PX as usize;
    for (row, label) in ["RGB", "depth", "mask"].iter().enumerate() {
        canvas.text(8, top + row * (tile_h + gap) + 8, label, 1, black);
    }
    let (bar_top, bar_h) = (top + tile_h + gap + 28, tile_h - 64);
    for y in 0..bar_h {
        let t = 1.0 - y as f32 / (bar_h - 1) as f32;
        canvas.fill(8, bar_top + y, 20, bar_top + y + 1, plasma(t));
    }
    canvas.text(24, bar_top, "near", 1, black);
    canvas.text(24, bar_top + bar_h - GLYPH_PX, "far", 1, black);
}

/// The mask's legend from `y` down: each id of `ids`, its colour and its name, `per_row` a
/// row.
fn mask_legend(canvas: &mut Canvas, ids: &[u8], y: usize, per_row: usize) {
    let names = mask_ids();
    for (k, id) in ids.iter().enumerate() {
        let x = 8 + (k % per_row) * LEGEND_ENTRY_PX;
        let y = y + (k / per_row) * 14;
        canvas.fill(x, y, x + 10, y + 10, [0, 0, 0]);
        canvas.fill(x + 1, y + 1, x + 9, y + 9, mask_colour(*id));
        let name = (names.iter())
            .find(|(i, _)| i == id)
            .map_or("unnamed", |(_, n)| n.as_str());
        let text = fit(&format!("{id} {name}"), LEGEND_ENTRY_PX / GLYPH_PX - 3);
        canvas.text(x + 14, y + 1, &text, 1, [0, 0, 0]);
    }
}

/// The mask ids a frame shows, each with its object's name ("6 gauze"), in id order.
pub fn mask_ids_in(frame: &Frame) -> Vec<String> {
    let mut ids: Vec<u8> = frame.mask.clone();
    ids.sort_unstable();
    ids.dedup();
    let names = mask_ids();
    (ids.iter())
        .map(|id| {
            let name = (names.iter())
                .find(|(i, _)| i == id)
                .map_or("unnamed", |(_, n)| n.as_str());
            format!("{id} {name}")
        })
        .collect()
}

/// A depth tile's range, nearest to farthest visible surface, millimetres ("" when empty).
pub fn depth_range_mm(frame: &Frame) -> String {
    let valid = frame.depth_m.iter().copied().filter(|z| *z > 0.0);
    let (near, far) = valid.fold((f32::INFINITY, 0f32), |(lo, hi), z| (lo.min(z), hi.max(z)));
    if near.is_finite() {
        format!("{:.0}-{:.0} mm", near * 1e3, far * 1e3)
    } else {
        String::new()
    }
}

/// The camera as datasets record it (row-major 4 x 4 `world_from_camera`).
pub fn camera_info(camera: &Camera) -> CameraInfo {
    let m = camera.world_from_camera.to_homogeneous();
    let mut world_from_camera = [[0.0; 4]; 4];
    for (r, row) in world_from_camera.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            *v = m[(r, c)];
        }
    }
    CameraInfo {
        width_px: camera.width_px,
        height_px: camera.height_px,
        fx_px: camera.fx_px,
        fy_px: camera.fy_px,
        cx_px: camera.cx_px,
        cy_px: camera.cy_px,
        near_m: camera.near_m,
        far_m: camera.far_m,
        world_from_camera,
    }
}

/// The mask id table of rendered masks: (id, class name) in id order.
pub fn mask_ids() -> Vec<(u8, String)> {
    crate::assets::MaskClass::ALL
        .iter()
        .map(|(class, name)| (class.id(), name.to_string()))
        .collect()
}

fn named_pose(name: &str, pose: &nalgebra::Isometry3<f64>) -> crate::episode::NamedPose {
    let q = pose.rotation.coords;
    crate::episode::NamedPose {
        name: name.into(),
        position_m: pose.translation.vector.into(),
        rotation_xyzw: [q[0], q[1], q[2], q[3]],
    }
}

/// The robot's frames for viewers: the PSM's remote centre of motion and link frames, the
/// instrument's shaft and its jaw pivot.
pub fn robot_frames(sim: &Simulator) -> Vec<crate::episode::NamedPose> {
    let mut frames: Vec<crate::episode::NamedPose> = sim
        .link_frames()
        .iter()
        .map(|(name, pose)| named_pose(name, pose))
        .collect();
    let instrument: InstrumentPose = sim.instrument_pose();
    frames.push(named_pose("psm_shaft", &instrument.world_from_shaft));
    frames.push(named_pose(
        "psm_jaw_pivot",
        &instrument.world_from_jaw_pivot,
    ));
    frames
}

/// [`scene_meshes`] of `scene` before its first step, drawn as `collect` draws episode `seed`.
pub fn scene_meshes_at_start(
    scene: &crate::scene::SceneSpec,
    seed: u64,
    randomize_appearance: bool,
) -> Vec<crate::episode::SceneMesh> {
    let appearance = if randomize_appearance {
        Appearance::randomized(seed)
    } else {
        Appearance::default()
    };
    let assets = SceneAssets::new(scene, seed, appearance);
    scene_meshes(
        &assets,
        &Simulator::new(SimConfig::default(), scene.clone()),
    )
}

/// The scene's meshes as data for viewers (the MCAP recorder's SceneUpdate), as they stand in
/// `sim` now: static parts in the world frame, movable objects in their `object_<i>` frames, the
/// instrument's shaft in `psm_shaft` and its wrist and jaws in `psm_jaw_pivot`.
pub fn scene_meshes(assets: &SceneAssets, sim: &Simulator) -> Vec<crate::episode::SceneMesh> {
    let object_poses = sim.object_poses();
    let instrument = sim.instrument_pose();
    // Without the clips, which come last: the parts a viewer places by frame.
    let instances = assets.instances(&object_poses, &instrument, &[]);
    let statics = instances.len() - object_poses.len() - 4;
    instances
        .iter()
        .enumerate()
        .map(|(i, instance)| {
            let (name, frame, frame_pose) = if i < statics {
                (
                    format!("static_{i}"),
                    "world".to_string(),
                    nalgebra::Isometry3::identity(),
                )
            } else if i < statics + object_poses.len() {
                let k = i - statics;
                let name = sim
                    .scene()
                    .objects
                    .get(k)
                    .map_or(format!("object_{k}"), |o| o.name.clone());
                (name, format!("object_{k}"), object_poses[k])
            } else if i == statics + object_poses.len() {
                (
                    "instrument_shaft".into(),
                    "psm_shaft".into(),
                    instrument.world_from_shaft,
                )
            } else {
                (
                    format!("instrument_{}", i - statics - object_poses.len()),
                    "psm_jaw_pivot".into(),
                    instrument.world_from_jaw_pivot,
                )
            };
            let frame_from_mesh = frame_pose.inverse() * instance.world_from_mesh;
            crate::episode::SceneMesh {
                name,
                frame,
                rgb: instance.material.albedo,
                positions_m: instance
                    .mesh
                    .positions
                    .iter()
                    .map(|p| {
                        let q = frame_from_mesh
                            * nalgebra::Point3::new(
                                f64::from(p[0]),
                                f64::from(p[1]),
                                f64::from(p[2]),
                            );
                        [q.x as f32, q.y as f32, q.z as f32]
                    })
                    .collect(),
                triangles: instance.mesh.triangles.clone(),
            }
        })
        .collect()
}

/// What a dataset (or an evaluation's recording) of this simulator states once: the camera,
/// the features (`features` picks depth, mask and object poses), the control rate, the robot,
/// the mask ids and the tool tip's workspace; `collection` says how the episodes were made.
pub fn dataset_info(
    camera: &Camera,
    features: crate::episode::FeatureSet,
    collection: crate::export::collection::Collection,
) -> crate::export::DatasetInfo {
    let camera = camera_info(camera);
    let workspace = crate::sim::control::Workspace::reference();
    crate::export::DatasetInfo {
        fps: crate::sim::Timing::default().control_hz,
        robot_type: "dvrk_psm".into(),
        features: crate::episode::standard_features(
            camera.height_px as usize,
            camera.width_px as usize,
            features,
        ),
        camera,
        mask_ids: mask_ids(),
        collection: Some(collection),
        generator: format!("surgvla {}", env!("CARGO_PKG_VERSION")),
        tip_workspace: Some(crate::episode::Aabb {
            min_m: workspace.min_m,
            max_m: workspace.max_m,
        }),
        input: None,
        provenance: Vec::new(),
        splits: Vec::new(),
        notes: Vec::new(),
        omitted: Vec::new(),
        episode_fields: Vec::new(),
        carried_keys: Default::default(),
        history: Vec::new(),
    }
}
