//! Episodes appended part by part ([`crate::export::writer::FormatWriter::append_part`]): a
//! recording's long episode written while it is read, never held whole. Each part becomes a
//! row group of the open data file, its video frames are encoded as they come (one encoder per
//! video feature, running across the parts) and appended to the open video files, and its
//! statistics fold frame by frame; at the last part the episode is recorded as a whole one is.
//! An episode that comes as one part is written as a whole one: the same bytes.

use super::table::frame_batch;
use super::work::{OpenEpisode, StatsFold, default_stats};
use super::writer::LeRobotFiles;
use crate::episode::EncodedFrame;
use crate::export::dir::DatasetDir;
use crate::export::error::ExportError;
use crate::export::info::DatasetInfo;
use crate::export::source::EpisodePart;
use crate::export::writer::EpisodeEncoder;
use crate::media::video::VideoEncoder;
use rayon::prelude::*;

impl LeRobotFiles {
    /// Appends the next part of an episode (see the module overview); returns the seconds
    /// spent encoding and on statistics.
    pub(super) fn write_part(
        &mut self,
        dir: &mut DatasetDir,
        info: &DatasetInfo,
        part: &EpisodePart,
    ) -> Result<f64, ExportError> {
        let episode = &part.episode;
        if part.first_step == 0 && part.last && self.parts.is_none() {
            let prepared = self.work(info).encode(episode)?;
            return self.write_prepared(dir, info, episode, prepared);
        }
        if !episode.encoded.is_empty() {
            return Err(ExportError::InvalidEpisode(format!(
                "episode {}: stored frames ({}) cannot arrive in parts",
                episode.meta.index, episode.encoded[0].feature
            )));
        }
        let mut open = match self.parts.take() {
            None if part.first_step == 0 => self.open_episode(dir, info, part)?,
            Some(open)
                if open.index == episode.meta.index
                    && open.task_indices.len() == part.first_step =>
            {
                open
            }
            _ => {
                return Err(ExportError::Internal(format!(
                    "episode {}: a part from step {} arrived out of order",
                    episode.meta.index, part.first_step
                )));
            }
        };
        let started = std::time::Instant::now();
        let first = part.first_step;
        let tasks: Vec<u64> = (first..part.steps_so_far())
            .map(|step| self.task_index(episode.meta.instruction_at(step)))
            .collect();
        let work = self.work(info);
        let (images, packets) = rayon::join(
            || work.encode_images(episode),
            || encode_video_part(&work, episode, &mut open.encoders),
        );
        let (images, packets) = (images?, packets?);
        for step in &episode.steps {
            open.fold.push(step);
        }
        let encode_secs = started.elapsed().as_secs_f64();
        self.append_video_packets(&packets)?;
        let batch = frame_batch(
            &self.parquet_columns(),
            episode,
            images,
            (open.first_index + first as u64, first),
            &tasks,
            info.fps,
        )?;
        let written = self.write_rows(dir, &batch)?;
        open.task_indices.extend(tasks);
        if !part.last {
            self.parts = Some(open);
            return Ok(encode_secs);
        }
        let tail = (open.encoders.into_iter())
            .map(VideoEncoder::finish)
            .collect::<Result<Vec<_>, _>>()?;
        self.append_video_packets(&tail)?;
        let videos = self.video_spans(&open.video_from);
        let mut stats = open.fold.finish_at_end(&self.work(info), episode);
        stats.extend(default_stats(
            open.index,
            f64::from(info.fps),
            &open.task_indices,
            open.first_index,
        ));
        let length = open.task_indices.len() as u64;
        let meta = &episode.meta;
        self.episode_done(
            dir,
            info,
            meta,
            (open.first_index, length),
            written,
            (stats, None),
            videos,
        )?;
        Ok(encode_secs)
    }

    /// Starts the episode whose first part is `part`: its statistics, and its video files and
    /// encoders.
    fn open_episode(
        &mut self,
        dir: &mut DatasetDir,
        info: &DatasetInfo,
        part: &EpisodePart,
    ) -> Result<OpenEpisode, ExportError> {
        let video_from = if self.video_features().is_empty() {
            Vec::new()
        } else {
            self.ready_videos(dir, info)?
        };
        let quality = self.options().video.map_or(0, |v| v.quality);
        let encoders = (self.video_features().iter())
            .map(|(key, codec)| {
                let size = super::writer::video_size(info, key);
                VideoEncoder::new(*codec, size, info.fps, quality)
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(OpenEpisode {
            index: part.episode.meta.index,
            first_index: self.frames_written(),
            task_indices: Vec::new(),
            fold: StatsFold::new(&self.work(info), Some(&part.episode)),
            encoders,
            video_from,
        })
    }
}

/// A part's packets per video feature, each feature's frames pushed to its encoder (features
/// in parallel).
fn encode_video_part(
    work: &super::work::EpisodeWork<'_>,
    episode: &crate::episode::Episode,
    encoders: &mut [VideoEncoder],
) -> Result<Vec<Vec<EncodedFrame>>, ExportError> {
    (work.video_features.par_iter())
        .zip(encoders.par_iter_mut())
        .map(|((key, _), encoder)| {
            let (pixels, _) = work.video_rgb(episode, key)?;
            let mut packets = Vec::with_capacity(pixels.len());
            for rgb in &pixels {
                packets.extend(encoder.push(rgb)?);
            }
            Ok(packets)
        })
        .collect()
}
