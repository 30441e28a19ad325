//! `surgvla render`: a task scene from the endoscope as PNG (RGB, depth, mask); the camera and
//! look flags `contact-sheet` shares ([`LookArgs`]).

use crate::error::CliError;
use std::path::PathBuf;
use surgvla::assets::{Appearance, SceneAssets};
use surgvla::collect::rollout;
use surgvla::eval::perturb::{Dimensions, Drawn, Variant};
use surgvla::policy::ExpertLibrary;
use surgvla::render::image::{depth_visualisation, mask_visualisation, write_png_file};
use surgvla::render::{Camera, Lighting, RenderOptions, Renderer};
use surgvla::sim::{SimConfig, Simulator};
use surgvla::task::TaskId;
use surgvla::view::render_simulator;

#[derive(clap::ValueEnum, Clone, Copy, Debug)]
enum CameraChoice {
    /// The endoscope (224 x 224, 60 deg).
    Endoscope,
    /// A wider overview of the workspace.
    Overview,
}

#[derive(clap::Args, Debug)]
pub(crate) struct RenderArgs {
    /// Task name (gauze_pick, ...) or id (T1-1, ...).
    #[arg(long, default_value = "gauze_pick")]
    task: TaskId,
    /// Episode seed: decides the spawn positions and shapes.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Run this many steps of the task's expert before rendering.
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u32).range(0..=100_000))]
    steps: u32,
    /// Output PNG for the RGB image.
    #[arg(long, value_parser = crate::app::png_path)]
    out: PathBuf,
    /// Also write the depth, colour-mapped (near bright, far dark, background black).
    #[arg(long)]
    depth: Option<PathBuf>,
    /// Also write the segmentation mask, colour-coded by object id.
    #[arg(long)]
    mask: Option<PathBuf>,
    #[arg(long, value_enum, default_value = "endoscope")]
    camera: CameraChoice,
    /// Preview a perturbation variant of `eval --perturb` (e.g. `smoke=2` or
    /// `camera_pose=3,blur=1`), drawn from the seed as an evaluation trial draws it.
    #[arg(long, value_name = "DIM=LEVEL,...")]
    perturb: Option<String>,
    #[command(flatten)]
    look: LookArgs,
}

#[derive(clap::Args, Debug)]
pub(crate) struct LookArgs {
    /// Supersampling of RGB per pixel edge (1 = off, 2 = 4 samples a pixel).
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u32).range(1..=4))]
    supersample: u32,
    /// Randomise light, tissue colour and texture contrast from the seed.
    #[arg(long)]
    randomize_appearance: bool,
    /// Light every surface per pixel (by default dense tissue is lit per vertex; slower).
    #[arg(long)]
    per_pixel_lighting: bool,
}

impl LookArgs {
    pub(crate) fn options(&self, seed: u64) -> (RenderOptions, Appearance) {
        let appearance = if self.randomize_appearance {
            Appearance::randomized(seed)
        } else {
            Appearance::default()
        };
        let options = RenderOptions {
            lighting: Lighting {
                allow_per_vertex: !self.per_pixel_lighting,
                ..appearance.lighting(Lighting::default())
            },
            supersample: self.supersample,
            ..RenderOptions::default()
        };
        (options, appearance)
    }
}

pub(crate) fn run_render(args: &RenderArgs) -> Result<(), CliError> {
    let dimensions = Dimensions::v1();
    let drawn = match &args.perturb {
        Some(given) => Variant::parse(given, dimensions)?.draw(dimensions, args.seed),
        None => Drawn::default(),
    };
    let config = drawn.task_config(surgvla::task::TaskConfig::default());
    let mut instance = args.task.instance(args.seed, &config)?;
    let start = SimConfig::default().world_from_start_tip.translation.vector;
    drawn.apply_to_instance(&mut instance, start);
    let scene = instance.scene.clone();
    let mut sim = Simulator::new(SimConfig::default(), scene.clone());
    if args.steps > 0 {
        let library = ExpertLibrary::builtin()?;
        let mut policy =
            library
                .plan(args.task)?
                .expert(&instance, &sim.observation(), args.seed)?;
        rollout(&mut sim, &mut policy, args.steps);
    }
    let camera = drawn.camera(&match args.camera {
        CameraChoice::Endoscope => Camera::endoscope(),
        CameraChoice::Overview => Camera::overview(),
    });
    let (options, appearance) = args.look.options(args.seed);
    let (options, appearance) = if args.perturb.is_some() {
        let lighting = drawn.appearance.lighting(Lighting {
            allow_per_vertex: options.lighting.allow_per_vertex,
            ..Lighting::default()
        });
        (
            RenderOptions {
                lighting,
                ..options
            },
            drawn.appearance,
        )
    } else {
        (options, appearance)
    };
    let assets = SceneAssets::new(&scene, args.seed, appearance);
    let mut renderer = Renderer::new(options);
    let mut frame = render_simulator(&assets, &mut renderer, &camera, &sim);
    let mut pools = surgvla::render::EffectsCache::default();
    drawn
        .effects
        .apply(&mut frame, u64::from(args.steps), &mut pools);
    let (w, h) = (frame.width_px, frame.height_px);
    write_png_file(&args.out, w, h, 3, &frame.rgb)?;
    // The images stay pixel-aligned with the RGB: their scale and legend are said here.
    if let Some(path) = &args.depth {
        write_png_file(path, w, h, 3, &depth_visualisation(&frame))?;
        say!(
            "{}: depth {}, nearest bright (yellow) to farthest dark (blue), nothing in range black",
            path.display(),
            surgvla::view::depth_range_mm(&frame)
        );
    }
    if let Some(path) = &args.mask {
        write_png_file(path, w, h, 3, &mask_visualisation(&frame))?;
        say!(
            "{}: mask ids {} (colours as in contact-sheet's legend)",
            path.display(),
            surgvla::view::mask_ids_in(&frame).join(", ")
        );
    }
    say!(
        "{} ({}){}, seed {}, step {}: {} triangles, wrote {}",
        args.task.code(),
        args.task.name(),
        args.perturb
            .as_ref()
            .map_or_else(String::new, |p| format!(" under {p}")),
        args.seed,
        sim.observation().step_index,
        assets.triangle_count(),
        args.out.display()
    );
    Ok(())
}
