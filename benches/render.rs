//! Criterion benches of the renderer.
//!
//! `render/endoscope_224`: one 224 x 224 endoscope frame (RGB + depth + mask) of a full scene:
//! drape, tray, kidney with its bleeding spot, gauze, needle, block and the instrument.
//! `render/endoscope_224_ss2`: the same with 2x2 supersampled RGB.
//! `render/endoscope_224_over_static`: the same frame drawn over the scene's kept static layer,
//! no mask, its buffers handed back after each frame: what `collect` pays per frame.
//! `effects/<dimension>`: the image effect of an evaluation's visual dimension at level 2 on
//! one such frame (the appearance and camera dimensions cost nothing per frame).

// Tests and benches fail by unwrapping, expecting and panicking (denied in the library).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use criterion::{Criterion, criterion_group, criterion_main};
use std::hint::black_box;
use surgvla::assets::{Appearance, SceneAssets};
use surgvla::render::{Camera, RenderOptions, Renderer};
use surgvla::scene::SceneSpec;
use surgvla::sim::{SimConfig, Simulator};
use surgvla::task::TaskId;

/// The benchmark scene: the kidney task with a gauze, a needle and a block added.
pub fn full_scene() -> SceneSpec {
    let mut scene = TaskId::Electrocoagulation.scene(0).unwrap();
    scene.objects = SceneSpec::one_of_each(0.0).objects;
    scene
}

fn bench_render(c: &mut Criterion) {
    let scene = full_scene();
    let sim = Simulator::new(SimConfig::default(), scene.clone());
    let assets = SceneAssets::new(&scene, 0, Appearance::default());
    let camera = Camera::endoscope();
    let poses = sim.object_poses();
    let instrument = sim.instrument_pose();
    let mut group = c.benchmark_group("render");
    println!("full scene: {} triangles", assets.triangle_count());
    for (name, supersample) in [("endoscope_224", 1), ("endoscope_224_ss2", 2)] {
        let mut renderer = Renderer::new(RenderOptions {
            supersample,
            ..RenderOptions::default()
        });
        group.bench_function(name, |b| {
            b.iter(|| {
                let instances = assets.instances(&poses, &instrument, &[]);
                black_box(renderer.render(&camera, &instances))
            })
        });
    }
    let mut renderer = Renderer::new(RenderOptions {
        mask: false,
        ..RenderOptions::default()
    });
    group.bench_function("endoscope_224_over_static", |b| {
        b.iter(|| {
            let instances = assets.instances(&poses, &instrument, &[]);
            let frame = renderer.render_over_static(&camera, &instances, assets.static_count());
            black_box(&frame);
            renderer.recycle(frame.rgb, frame.depth_m, frame.mask);
        })
    });
    group.finish();
}

fn bench_effects(c: &mut Criterion) {
    use surgvla::eval::perturb::{Dimensions, Variant};
    use surgvla::render::EffectsCache;
    let scene = full_scene();
    let sim = Simulator::new(SimConfig::default(), scene.clone());
    let assets = SceneAssets::new(&scene, 0, Appearance::default());
    let instances = assets.instances(&sim.object_poses(), &sim.instrument_pose(), &[]);
    let frame = Renderer::new(RenderOptions::default()).render(&Camera::endoscope(), &instances);
    let dimensions = Dimensions::v1();
    let mut group = c.benchmark_group("effects");
    for name in [
        "light_colour",
        "light_direction",
        "smoke",
        "blood",
        "sensor_noise",
        "blur",
    ] {
        let variant = Variant::parse(&format!("{name}=2"), dimensions).unwrap();
        let effects = variant.draw(dimensions, 7).effects;
        let mut pools = EffectsCache::default();
        let mut index = 0;
        group.bench_function(name, |b| {
            b.iter(|| {
                let mut copy = frame.clone();
                index += 1;
                effects.apply(&mut copy, index, &mut pools);
                black_box(copy)
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench_render, bench_effects);
criterion_main!(benches);
