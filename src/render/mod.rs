//! The CPU renderer: pinhole cameras ([`camera`]), triangle meshes and primitive builders
//! ([`mesh`]), materials and procedural patterns ([`material`]), the rasterizer ([`raster`]),
//! image-space effects ([`effects`]) and PNG output ([`image`]).
//!
//! It knows nothing of the simulator or of rapier: it takes meshes, poses, materials, mask ids
//! and a camera, and returns RGB u8, depth f32 metres along the optical axis (0 = background)
//! and a u8 mask, pixel-aligned.

pub mod camera;
pub mod effects;
pub mod image;
pub mod material;
pub mod mesh;
pub mod raster;

pub use camera::Camera;
pub use effects::{EffectsCache, ImageEffects};
pub use material::{Material, Pattern};
pub use mesh::Mesh;
pub use raster::{Frame, Instance, Lighting, Rasterizer};

/// Render settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderOptions {
    pub lighting: Lighting,
    /// RGB is rendered at this many samples per pixel edge and box-filtered (1 = off). Depth
    /// and mask always sample pixel centres, so they stay aligned with RGB.
    pub supersample: u32,
    /// Whether frames carry the segmentation mask (false: an empty one, for a dataset that
    /// stores none; RGB and depth are the same either way).
    pub mask: bool,
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            lighting: Lighting::default(),
            supersample: 1,
            mask: true,
        }
    }
}

/// A renderer with reusable buffers.
#[derive(Debug, Default)]
pub struct Renderer {
    pub options: RenderOptions,
    rasterizer: Rasterizer,
}

impl Renderer {
    pub fn new(options: RenderOptions) -> Self {
        let mut rasterizer = Rasterizer::default();
        rasterizer.skip_mask = !options.mask;
        Renderer {
            options,
            rasterizer,
        }
    }

    /// Renders the instances seen by `camera`, the first `statics` of which stand still from
    /// call to call (see [`raster::Rasterizer::render_over_static`]: the same pixels as
    /// [`Renderer::render`], their layer drawn once). Supersampled rendering draws everything.
    pub fn render_over_static(
        &mut self,
        camera: &Camera,
        instances: &[Instance<'_>],
        statics: usize,
    ) -> Frame {
        if self.options.supersample > 1 {
            return self.render(camera, instances);
        }
        self.rasterizer
            .render_over_static(camera, instances, &self.options.lighting, statics)
    }

    /// Takes back a frame's buffers for the next [`Renderer::render_over_static`] frame to be
    /// drawn into (no allocation, and memory the core has just used).
    pub fn recycle(&mut self, rgb: Vec<u8>, depth_m: Vec<f32>, mask: Vec<u8>) {
        self.rasterizer.recycle(rgb, depth_m, mask);
    }

    /// Renders the instances seen by `camera`.
    pub fn render(&mut self, camera: &Camera, instances: &[Instance<'_>]) -> Frame {
        self.rasterizer.render(
            camera,
            instances,
            &self.options.lighting,
            self.options.supersample,
        )
    }
}
