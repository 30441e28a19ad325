//! Episodes made from the frames the second pass hands over ([`Making`]): each frame's
//! messages turned into features by the preset as it arrives (raw pixels held only until their
//! batch is encoded), images encoded as PNG in parallel batches, and the episode handed on in
//! parts of about [`PART_BYTES`] of images (an [`EpisodePart`]), the last at its end mark: a
//! long recording is never held whole. Every camera must keep its size.

use crate::episode::{Episode, EpisodeMeta, FeatureValue, PixelStats, Step, TaskChange};
use crate::export::source::EpisodePart;
use crate::export::stats::{ImageStats, LastFrame};
use crate::ingest::dvrk::{DvrkFrame, DvrkPreset, FeatureInfo};
use crate::ingest::error::IngestError;
use crate::ingest::frames::Handed;
use rayon::prelude::*;
use std::path::Path;

/// Frames whose pixels are gathered before they are encoded together.
pub const BATCH_FRAMES: usize = 32;

/// Encoded image bytes after which the steps held are handed on as a part of their episode
/// (at the next frame, so that no part is empty); a part is a row group of a LeRobot data
/// file.
pub const PART_BYTES: usize = 32 << 20;

/// How an episode's frames are encoded and handed on: images encoded in parallel batches of
/// `batch_frames` frames, the steps held handed on as a part of their episode once their
/// images reach `part_bytes` (see the module overview). The default outside tests.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Parting {
    pub batch_frames: usize,
    pub part_bytes: usize,
}

impl Default for Parting {
    fn default() -> Self {
        Parting {
            batch_frames: BATCH_FRAMES,
            part_bytes: PART_BYTES,
        }
    }
}

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
    /// Steps encoded and not handed on yet: the episode's from `first_step` on, and their
    /// images' bytes.
    steps: Vec<Step>,
    first_step: usize,
    held_bytes: usize,
    /// Whether the recording has instruction messages to wait for (no task given): until the
    /// first one, the episode's task is unknown and nothing is handed on.
    awaits_instruction: bool,
    has_instructions: bool,
    parting: Parting,
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

/// A part of an episode made, with what its input's frames showed so far.
pub struct Made {
    pub part: EpisodePart,
    /// Each camera's (height, width).
    pub sizes: Option<Vec<(usize, usize)>>,
    /// The frames the first frame's poses are in (state, action `info`).
    pub pose_info: Option<(FeatureInfo, FeatureInfo)>,
}

impl<'a> Making<'a> {
    /// Episodes of `path`, the first numbered `next_index`; `sizes` as earlier inputs had them.
    /// `instructions`: the recording has instruction messages (read without a task given).
    pub fn new(
        path: &'a Path,
        preset: &'a DvrkPreset,
        (task, instructions): (Option<&'a str>, bool),
        parting: Parting,
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
            pending: Vec::with_capacity(parting.batch_frames),
            parting,
            steps: Vec::new(),
            first_step: 0,
            held_bytes: 0,
            awaits_instruction: task.is_none() && instructions,
            has_instructions: instructions,
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

    /// Takes what the second pass hands over: a part of the episode when enough is held and
    /// a frame continues it, the last part at the episode's end.
    pub fn take(&mut self, handed: Handed) -> Result<Option<Made>, IngestError> {
        match handed {
            Handed::Frame(frame) => {
                let due = self.held_bytes >= self.parting.part_bytes;
                let part = (due && !self.awaits_instruction).then(|| self.made(false));
                let time_ns = frame.time_ns;
                let features = (self.preset.frame(&frame.values))
                    .map_err(|problem| self.bad(time_ns, problem))?;
                self.check_sizes(time_ns, &features)?;
                if self.pose_info.is_none() {
                    self.pose_info = Some(self.preset.pose_info(&frame.values));
                }
                if self.task.is_none() {
                    let step = self.first_step + self.steps.len() + self.pending.len();
                    self.note_instruction(step, features.instruction.as_deref());
                }
                self.pending.push((time_ns, features));
                if self.pending.len() >= self.parting.batch_frames {
                    self.encode()?;
                }
                Ok(part)
            }
            Handed::EpisodeEnd => {
                self.encode()?;
                Ok(Some(self.made(true)))
            }
        }
    }

    /// The steps held as a part of the episode (its last: the episode's end), with the
    /// episode's task so far and each camera's statistics over the episode so far.
    fn made(&mut self, last: bool) -> Made {
        let instruction = match self.task {
            Some(task) => task.to_string(),
            None => self.instruction.clone().unwrap_or_default(),
        };
        let stats = if last {
            std::mem::take(&mut self.camera_stats)
        } else {
            self.camera_stats.clone()
        };
        let image_stats = (self.preset.cameras.iter())
            .zip(stats)
            .filter_map(|((name, _), stats)| {
                let exact = serde_json::to_string(&stats).ok()?;
                Some((
                    format!("observation.images.{name}"),
                    PixelStats::Exact(exact),
                ))
            })
            .collect();
        let task_changes = if last {
            std::mem::take(&mut self.changes)
        } else {
            self.changes.clone()
        };
        let steps = std::mem::take(&mut self.steps);
        let first_step = self.first_step;
        self.first_step += steps.len();
        self.held_bytes = 0;
        let episode = Episode {
            meta: EpisodeMeta {
                task_changes,
                ..EpisodeMeta::foreign(self.next_index, instruction)
            },
            steps,
            encoded: Vec::new(),
            image_stats,
            stored_rows: None,
        };
        if last {
            self.instruction = None;
            self.latest = None;
            self.first_step = 0;
            self.awaits_instruction = self.task.is_none() && self.has_instructions;
            self.next_index += 1;
        }
        Made {
            part: EpisodePart {
                episode,
                first_step,
                last,
            },
            sizes: self.sizes.clone(),
            pose_info: self.pose_info.clone(),
        }
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
            None => {
                self.instruction = Some(instruction.to_string());
                self.awaits_instruction = false;
            }
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
            self.held_bytes += (step.other.iter())
                .map(|value| match value {
                    FeatureValue::Image(bytes) => bytes.len(),
                    _ => 0,
                })
                .sum::<usize>();
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
