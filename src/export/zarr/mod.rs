//! The DP3 zarr v2 store (3D Diffusion Policy's replay-buffer layout), written by
//! [`ZarrWriter`]:
//! ```text
//! .zgroup, .zattrs            the root group; .zattrs holds surgvla's metadata and the cloud settings
//! data/point_cloud            (T, N, 6) float32: x y z (world, m), r g b (0..255); 7 with the mask id
//! data/state, data/action     (T, 7) float32
//! data/img, data/depth        (T, H, W, 3) uint8 and (T, H, W) float32 metres, with images on
//! meta/episode_ends           (E,) int64, cumulative exclusive ends
//! ```
//! Every episode's frames are concatenated along T; chunks of [`array::CHUNK_ROWS`] along T,
//! zstd level 3. Why our own writer: see [`array`]. Clouds come from
//! [`crate::export::pointcloud`]. A checkpoint every [`CHECKPOINT_EPISODES`] episodes writes the
//! partial chunks too, and a resume reads them back.

pub mod array;
pub mod check;
mod format;
mod merge;
mod writer;

pub use format::ZarrFormat;
pub use writer::{CHECKPOINT_EPISODES, MANIFEST, State, ZarrOptions, ZarrStore, ZarrWriter};
