//! Episodes made from the frames the second pass hands over ([`Making`]): each frame's
//! messages turned into features by the preset as it arrives (raw pixels held only until their
//! batch is encoded), images encoded as PNG in parallel batches, an episode handed on at each
//! end mark. Every camera must keep its size.

use crate::episode::{Episode, EpisodeMeta, FeatureValue, PixelStats, Step, TaskChange};
use crate::export::stats::{ImageStats, LastFrame};
use crate::ingest::dvrk::{DvrkFrame, DvrkPreset, FeatureInfo};
use crate::ingest::error::IngestError;
use crate::ingest::frames::Handed;
use rayon::prelude::*;
use std::path::Path;

/// Frames whose pixels are gathered before they are encoded together.
const BATCH_FRAMES: usize = 32;

/// An input's episodes being made (see the module overview).
pub struct Making<'a> {
    path: &'a Path,
    preset: &'a DvrkPreset,
    /// The task given; None: each frame's latest instruction.
    task: Option<&'a str>,
    /// Each frame's instruction as a text feature after the action.
    text: bool,
    /// Each camera's (height, width), from the first frame.
    sizes: Option<Vec<(usize, usize)>>,
    /// Frames not yet encoded: (time, features).
    pending: Vec<(i64, DvrkFrame)>,
    steps: Vec<Step>,
    /// Each camera's pixel statistics over the episode's frames so far, folded in frame
    /// order as a writer would from the images (see [`frame_stats`]).
    camera_stats: Vec<ImageStats>,
    /// The episode's first instruction, the latest, and where it changed since (without a
    /// task given).
    instruction: Option<String>,
    latest: Option<String>,
    changes: Vec<TaskChange>,
    next_index: u64,
    /// The frames of the first frame's poses (state, action `info`).
    pose_info: Option<(FeatureInfo, FeatureInfo)>,
}

/// An episode made, with what its input's frames showed so far.
pub struct Made {
    pub episode: Episode,
    /// Each camera's (height, width).
    pub sizes: Option<Vec<(usize, usize)>>,
    /// The frames the first frame's poses are in (state, action `info`).
    pub pose_info: Option<(FeatureInfo, FeatureInfo)>,
}

impl<'a> Making<'a> {
    /// Episodes of `path`, the first numbered `next_index`; `sizes` as earlier inputs had them.
    pub fn new(
        path: &'a Path,
        preset: &'a DvrkPreset,
        task: Option<&'a str>,
        text: bool,
        sizes: Option<Vec<(usize, usize)>>,
        next_index: u64,
    ) -> Making<'a> {
        Making {
            path,
            preset,
            task,
            text,
            sizes,
            pending: Vec::with_capacity(BATCH_FRAMES),
            steps: Vec::new(),
            camera_stats: Vec::new(),
            instruction: None,
            latest: None,
            changes: Vec::new(),
            next_index,
            pose_info: None,
        }
    }

    fn bad(&self, time_ns: i64, problem: String) -> IngestError {
        IngestError::Frame {
            path: self.path.to_path_buf(),
            time_ns,
            problem,
        }
    }

    /// Takes what the second pass hands over; an episode's end gives the episode.
    pub fn take(&mut self, handed: Handed) -> Result<Option<Made>, IngestError> {
        match handed {
            Handed::Frame(frame) => {
                let time_ns = frame.time_ns;
                let features = (self.preset.frame(&frame.values))
                    .map_err(|problem| self.bad(time_ns, problem))?;
                self.check_sizes(time_ns, &features)?;
                if self.pose_info.is_none() {
                    self.pose_info = Some(self.preset.pose_info(&frame.values));
                }
                if self.task.is_none() {
                    let step = self.steps.len() + self.pending.len();
                    self.note_instruction(step, features.instruction.as_deref());
                }
                self.pending.push((time_ns, features));
                if self.pending.len() == BATCH_FRAMES {
                    self.encode()?;
                }
            }
            Handed::EpisodeEnd => {
                self.encode()?;
                let instruction = match self.task {
                    Some(task) => task.to_string(),
                    None => self.instruction.take().unwrap_or_default(),
                };
                self.latest = None;
                let image_stats = (self.preset.cameras.iter())
                    .zip(std::mem::take(&mut self.camera_stats))
                    .filter_map(|((name, _), stats)| {
                        let exact = serde_json::to_value(stats).ok()?;
                        Some((
                            format!("observation.images.{name}"),
                            PixelStats::Exact(exact),
                        ))
                    })
                    .collect();
                let episode = Episode {
                    meta: EpisodeMeta {
                        task_changes: std::mem::take(&mut self.changes),
                        ..EpisodeMeta::foreign(self.next_index, instruction)
                    },
                    steps: std::mem::take(&mut self.steps),
                    encoded: Vec::new(),
                    image_stats,
                };
                self.next_index += 1;
                return Ok(Some(Made {
                    episode,
                    sizes: self.sizes.clone(),
                    pose_info: self.pose_info.clone(),
                }));
            }
        }
        Ok(None)
    }

    /// Notes step `step`'s instruction (the latest instruction message, if any yet): the
    /// episode's first, or a change. Steps before the first message take the first.
    fn note_instruction(&mut self, step: usize, instruction: Option<&str>) {
        let Some(instruction) = instruction else {
            return;
        };
        match &self.latest {
            Some(latest) if latest == instruction => return,
            Some(_) => self.changes.push(TaskChange {
                first_step: step as u64,
                instruction: instruction.to_string(),
            }),
            None => self.instruction = Some(instruction.to_string()),
        }
        self.latest = Some(instruction.to_string());
    }

    fn check_sizes(&mut self, time_ns: i64, frame: &DvrkFrame) -> Result<(), IngestError> {
        let cameras = frame.images.iter().map(|i| (i.height, i.width));
        let depths = frame.depths.iter().map(|d| (d.height, d.width));
        let here: Vec<(usize, usize)> = cameras.chain(depths).collect();
        let known = self.sizes.get_or_insert_with(|| here.clone());
        let changed = (here.iter().zip(known.iter()).enumerate())
            .find(|(_, (now, before))| now != before)
            .map(|(c, (now, before))| (c, *now, *before));
        if let Some((c, now, before)) = changed {
            let name = (self.preset.image_topics().nth(c)).map_or("?", |(name, _)| name.as_str());
            return Err(self.bad(
                time_ns,
                format!(
                    "camera {name} is {}x{} where earlier frames are {}x{} (width x height)",
                    now.1, now.0, before.1, before.0
                ),
            ));
        }
        Ok(())
    }

    /// Encodes the pending frames' images in parallel into steps.
    fn encode(&mut self) -> Result<(), IngestError> {
        let pending = std::mem::take(&mut self.pending);
        let text = self.text.then_some(self.task);
        let steps: Vec<Result<EncodedFrame, (i64, String)>> = pending
            .into_par_iter()
            .map(|(time_ns, frame)| {
                let stats = frame.images.iter().map(|i| frame_stats(&i.rgb)).collect();
                let step = step(frame, text).map_err(|problem| (time_ns, problem))?;
                Ok((step, stats))
            })
            .collect();
        for step in steps {
            let (step, stats) = step.map_err(|(time_ns, problem)| self.bad(time_ns, problem))?;
            if self.camera_stats.is_empty() {
                self.camera_stats = vec![ImageStats::unit_scaled(3); stats.len()];
            }
            for (total, (frame, histograms)) in self.camera_stats.iter_mut().zip(stats) {
                total.merge(&frame);
                total.add_histograms(&histograms);
            }
            self.steps.push(step);
        }
        Ok(())
    }
}

/// One frame's statistics of an RGB image's pixels and its pixel counts.
type FrameStats = (ImageStats, Vec<Vec<u64>>);

/// A frame's step, and its cameras' [`FrameStats`].
type EncodedFrame = (Step, Vec<FrameStats>);

/// What a writer's statistics take from one frame's RGB pixels (a frame's sums, its counts
/// apart), so that folding them in frame order gives exactly the writer's accumulator.
fn frame_stats(rgb: &[u8]) -> FrameStats {
    let fresh = ImageStats::unit_scaled(3);
    let mut histograms = fresh.empty_histograms();
    let mut frame = fresh.without_histograms();
    frame.push_u8_counting_since(rgb, &mut histograms, &mut LastFrame::default());
    (frame, histograms)
}

/// A step of a frame's features, in feature order: each camera (PNG), each depth camera (16-bit
/// PNG, millimetres), then state and action,
/// each mapped feature, then with `text` (Some(the task given)) the frame's instruction. Every feature is one of
/// the dataset's own (not surgvla's simulated ones), as any format reads a dataset another
/// tool made.
fn step(frame: DvrkFrame, text: Option<Option<&str>>) -> Result<Step, String> {
    let mut step = Step::empty();
    for image in frame.images {
        let png = crate::media::image::encode_png(
            image.width,
            image.height,
            3,
            &image.rgb,
            crate::media::image::PngLevel::Fast,
        )
        .map_err(|e| e.to_string())?;
        step.other.push(FeatureValue::Image(png));
    }
    for depth in frame.depths {
        let png = crate::media::image::encode_png16(
            depth.width,
            depth.height,
            &depth.depth_mm,
            crate::media::image::PngLevel::Fast,
        )
        .map_err(|e| e.to_string())?;
        step.other.push(FeatureValue::Image(png));
    }
    step.other.push(FeatureValue::Float32(frame.state));
    step.other.push(FeatureValue::Float32(frame.action));
    for values in frame.mapped {
        step.other.push(FeatureValue::Float32(values));
    }
    if let Some(task) = text {
        let instruction = task.map(String::from).or(frame.instruction);
        step.other
            .push(FeatureValue::Text(instruction.unwrap_or_default()));
    }
    Ok(step)
}
