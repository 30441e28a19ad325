//! Recordings as an [`EpisodeSource`]: each input's first pass and synchronisation plan when
//! opened, then its episodes (second pass, [`DvrkPreset::frame`]) as they are read, so any sink
//! `convert` writes to takes them. Features: each camera as an image
//! (`observation.images.<name>`, PNG), the state and action of every arm as float32 vectors of
//! 8 per arm (`observation.state`, `action`, each value named): a dataset of the robot's own
//! features, as every format reads one another tool made.
//!
//! An input's episodes are made on a thread of their own as its frames are handed over, and
//! handed on in parts ([`crate::export::source::EpisodePart`], about
//! [`crate::ingest::episodes::PART_BYTES`] of images each) one at a time as they are read
//! ([`Producing`]): a sink that writes parts (LeRobot) holds a part, not an episode, so memory
//! follows neither the inputs' length nor their number; for the others the parts are gathered
//! into episodes. The first input's reading starts when the source opens, and its first part is
//! made then, for the images' size.

use crate::episode::{Dtype, Episode, FeatureKind, FeatureSpec};
use crate::export::error::ExportError;
use crate::export::info::DatasetInfo;
use crate::export::source::EpisodeSource;
use crate::export::source::{EpisodePart, Gathering};
use crate::ingest::builtin::ros2_types;
use crate::ingest::dvrk::{DvrkPreset, FeatureInfo, INSTRUCTION_TOPIC};
use crate::ingest::episodes::Made;
use crate::ingest::episodes::Making;
pub use crate::ingest::episodes::Parting;
use crate::ingest::error::IngestError;
use crate::ingest::extract::camera_intrinsics;
use crate::ingest::frames::second_pass;
use crate::ingest::msgdef::MessageDefs;
use crate::ingest::open::BagInput;
use crate::ingest::stamps::{Clock, TopicSpec, first_pass_keeping};
use crate::ingest::sync::{SyncOptions, SyncPlan, SyncReport, plan};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, sync_channel};

/// How recordings are ingested.
#[derive(Clone, Debug, PartialEq)]
pub struct IngestOptions {
    pub preset: DvrkPreset,
    pub clock: Clock,
    pub sync: SyncOptions,
    /// The task of every episode; None: the recording's `/instruction` topic.
    pub task: Option<String>,
    /// (topic, ns) added to a topic's times (`--time-offset`); every topic one the preset reads.
    pub offsets_ns: Vec<(String, i64)>,
    /// Each frame's instruction as a text feature, `instruction.text` (Open-H's per-frame
    /// instruction): the task given, else the latest instruction message at or before the
    /// frame (an event stream: no frame is written before its first message).
    pub instruction_text: bool,
    /// Named ranges of the dataset's episode indices (`--split`), checked against the episodes
    /// the inputs make.
    pub splits: Vec<(String, std::ops::Range<u64>)>,
    /// Where a zstd-compressed sqlite3 file of a ROS 2 bag is decompressed for the moment it
    /// is opened (the output folder); None refuses such bags.
    pub scratch: Option<std::path::PathBuf>,
    /// How an episode's frames are encoded and handed on in parts.
    pub parting: Parting,
}

impl IngestOptions {
    /// Refuses an offset for a topic the preset does not read, and a topic read twice (a
    /// mapped feature on a camera's topic, say).
    pub fn check(&self) -> Result<(), IngestError> {
        let names: Vec<&str> = (self.preset.image_topics().map(|(name, _)| name.as_str()))
            .chain(self.preset.mapped.iter().map(|m| m.name.as_str()))
            .collect();
        for (i, name) in names.iter().enumerate() {
            if names[..i].contains(name) {
                return Err(IngestError::Usage(format!(
                    "{name} is given twice (a camera, a depth camera or a mapped feature): each names one feature"
                )));
            }
        }
        let topics = self.preset.topics();
        for (i, topic) in topics.iter().enumerate() {
            if topics[..i].iter().any(|t| t.topic == topic.topic) {
                return Err(IngestError::Usage(format!(
                    "{} is read twice (by the preset, a camera or --map): each topic makes one feature",
                    topic.topic
                )));
            }
        }
        for (topic, _) in &self.offsets_ns {
            if !topics.iter().any(|t| &t.topic == topic) {
                let read: Vec<&str> = topics.iter().map(|t| t.topic.as_str()).collect();
                return Err(IngestError::Usage(format!(
                    "--time-offset names {topic}, which is not read (the topics read: {})",
                    read.join(", ")
                )));
            }
        }
        Ok(())
    }

    /// The preset's topics with their offsets.
    fn topics(&self) -> Vec<TopicSpec> {
        let mut topics = self.preset.topics();
        for topic in &mut topics {
            for (name, offset_ns) in &self.offsets_ns {
                if *name == topic.topic {
                    topic.offset_ns = topic.offset_ns.saturating_add(*offset_ns);
                }
            }
        }
        topics
    }
}

/// One input, planned: what is kept of it until its episodes are made (its plan is made
/// again then, so memory does not grow with the number of inputs; the first input's, made
/// when the source opens, is used as it is).
struct Input {
    path: PathBuf,
    report: SyncReport,
    plan: Option<Planned>,
}

/// One input's topics and plan.
struct Planned {
    topics: Vec<TopicSpec>,
    plan: SyncPlan,
    /// Per camera, what its `CameraInfo` states (empty without one).
    camera_info: Vec<FeatureInfo>,
}

/// Recordings read as episodes (see the module overview).
pub struct IngestSource {
    info: DatasetInfo,
    options: IngestOptions,
    builtin: MessageDefs,
    inputs: Vec<Input>,
    /// The next input whose episodes are to be made.
    next_input: usize,
    /// The input whose episodes are being made, and the next of them, already received.
    producing: Option<Producing>,
    ready: Option<EpisodePart>,
    next_index: u64,
    total: u64,
    /// Each camera's (height, width), from the first frame made.
    image_sizes: Option<Vec<(usize, usize)>>,
    /// The first input's cameras' `CameraInfo` and poses' frames, for the features' `info`.
    camera_info: Vec<FeatureInfo>,
    pose_info: Option<(FeatureInfo, FeatureInfo)>,
    /// Episodes of the next input skipped (a resume): made, then dropped.
    skipped: usize,
    failed: bool,
}

impl IngestSource {
    /// Plans every input (one read each, headers only) and makes the first one's episodes.
    pub fn open(paths: &[PathBuf], options: IngestOptions) -> Result<IngestSource, IngestError> {
        options.check()?;
        let builtin = ros2_types().map_err(|source| IngestError::Definition {
            path: PathBuf::new(),
            topic: String::new(),
            type_name: "a built-in type".into(),
            source: Box::new(source),
        })?;
        let mut inputs = Vec::with_capacity(paths.len());
        for path in paths {
            let planned = planned(path, &options, &builtin)?;
            let first = inputs.is_empty();
            inputs.push(Input {
                path: path.clone(),
                report: planned.plan.report.clone(),
                plan: first.then_some(planned),
            });
        }
        let total = inputs.iter().map(|i| i.report.episodes.len() as u64).sum();
        check_splits(&options.splits, total)?;
        let mut source = IngestSource {
            info: DatasetInfo::from_surgvla_json(&serde_json::Value::Null, 0, "dvrk", Vec::new()),
            options,
            builtin,
            inputs,
            next_input: 0,
            producing: None,
            ready: None,
            next_index: 0,
            total,
            image_sizes: None,
            camera_info: Vec::new(),
            pose_info: None,
            skipped: 0,
            failed: false,
        };
        source.start_next_input()?;
        source.ready = source.receive()?;
        source.info = source.dataset_info();
        Ok(source)
    }

    /// The options the recordings are read with.
    pub fn options(&self) -> &IngestOptions {
        &self.options
    }

    /// Each input's synchronisation report.
    pub fn reports(&self) -> Vec<(&Path, &SyncReport)> {
        (self.inputs.iter())
            .map(|i| (i.path.as_path(), &i.report))
            .collect()
    }

    /// The reports as files to write into a dataset of `format` (see
    /// [`crate::ingest::report`]).
    pub fn sync_files(
        &self,
        format: crate::export::Format,
    ) -> Result<Vec<(String, Vec<u8>)>, ExportError> {
        let dir = crate::ingest::report::sync_dir(format);
        crate::ingest::report::sync_files(&self.reports(), dir).map_err(|source| {
            ExportError::Json {
                path: dir.into(),
                source,
            }
        })
    }

    /// What a resume compares: every input's name and size, and the options.
    fn identity(&self) -> String {
        let mut crc = crc32c::crc32c(format!("{:?}", self.options).as_bytes());
        for input in &self.inputs {
            let name = input.path.file_name().unwrap_or_default();
            let line = format!(
                "{}\0{}\0",
                name.to_string_lossy(),
                content_sizes(&input.path)
            );
            crc = crc32c::crc32c_append(crc, line.as_bytes());
        }
        format!(
            "{} recordings ingested, crc32c {crc:08x}",
            self.inputs.len()
        )
    }

    fn dataset_info(&self) -> DatasetInfo {
        let preset = &self.options.preset;
        let sizes = self.image_sizes.clone().unwrap_or_default();
        // Cameras (RGB), then depth cameras (one channel, millimetres), by index.
        let image = |c: usize, (name, topic): &(String, String)| {
            let (height, width) = sizes.get(c).copied().unwrap_or((0, 0));
            let depth = c >= preset.cameras.len();
            let mut info = FeatureInfo::new();
            if depth {
                info.insert("is_depth_map".into(), true.into());
                info.insert("depth_unit".into(), "mm".into());
            }
            info.insert("camera.topic".into(), topic.as_str().into());
            info.extend(self.camera_info.get(c).cloned().unwrap_or_default());
            FeatureSpec {
                name: format!("observation.images.{name}"),
                dtype: Dtype::Image,
                shape: vec![height, width, if depth { 1 } else { 3 }],
                names: ["height", "width", "channels"].map(String::from).to_vec(),
                kind: FeatureKind::Other,
                video: None,
                info,
            }
        };
        let (state_info, action_info) = self.pose_info.clone().unwrap_or_default();
        let vector = |name: &str, info: FeatureInfo| FeatureSpec {
            name: name.into(),
            dtype: Dtype::Float32,
            shape: vec![preset.value_names().len()],
            names: preset.value_names(),
            kind: FeatureKind::Other,
            video: None,
            info,
        };
        let mut features: Vec<FeatureSpec> = (preset.image_topics().enumerate())
            .map(|(c, camera)| image(c, camera))
            .collect();
        features.push(vector("observation.state", state_info));
        features.push(vector("action", action_info));
        for mapped in &preset.mapped {
            let mut info = FeatureInfo::new();
            info.insert("ros.topic".into(), mapped.topic.as_str().into());
            features.push(FeatureSpec {
                name: mapped.name.clone(),
                dtype: Dtype::Float32,
                shape: vec![mapped.len()],
                names: mapped.value_names(),
                kind: FeatureKind::Other,
                video: None,
                info,
            });
        }
        if self.options.instruction_text {
            features.push(FeatureSpec {
                name: INSTRUCTION_FEATURE.into(),
                dtype: Dtype::String,
                shape: vec![1],
                names: Vec::new(),
                kind: FeatureKind::Other,
                video: None,
                info: Default::default(),
            });
        }
        let mut info = DatasetInfo::from_surgvla_json(
            &serde_json::Value::Null,
            self.options.sync.fps,
            "dvrk",
            features,
        );
        // Not surgvla's own episodes: the generator stays empty (a foreign dataset to every
        // format), the card says where they came from.
        info.provenance = crate::ingest::report::provenance(&self.reports());
        info.input = Some(self.identity());
        info.splits.clone_from(&self.options.splits);
        info
    }

    /// Starts making the next input's episodes on a thread of their own.
    fn start_next_input(&mut self) -> Result<(), IngestError> {
        let Some(input) = self.inputs.get_mut(self.next_input) else {
            return Ok(());
        };
        self.next_input += 1;
        let kept = input.plan.take();
        let input = &*input;
        let planned = match kept {
            Some(planned) => planned,
            None => planned(&input.path, &self.options, &self.builtin)?,
        };
        if self.next_input == 1 {
            self.camera_info.clone_from(&planned.camera_info);
        }
        let episodes = input.report.episodes.len();
        let task = Producer {
            path: input.path.clone(),
            options: self.options.clone(),
            builtin: self.builtin.clone(),
            planned,
            sizes: self.image_sizes.clone(),
            first_index: self.next_index,
        };
        self.next_index += episodes as u64;
        self.producing = Some(task.start(episodes, std::mem::take(&mut self.skipped)));
        Ok(())
    }

    /// The next part made, the sizes and frames it showed noted; None after the last.
    fn receive(&mut self) -> Result<Option<EpisodePart>, IngestError> {
        loop {
            let Some(producing) = &mut self.producing else {
                if self.next_input == self.inputs.len() {
                    return Ok(None);
                }
                self.start_next_input()?;
                continue;
            };
            let Some(made) = producing.next()? else {
                self.producing = None;
                continue;
            };
            self.image_sizes = made.sizes;
            if self.pose_info.is_none() {
                self.pose_info = made.pose_info;
            }
            return Ok(Some(made.part));
        }
    }
}

/// What the thread making an input's episodes owns.
struct Producer {
    path: PathBuf,
    options: IngestOptions,
    builtin: MessageDefs,
    planned: Planned,
    /// Each camera's size as earlier inputs had it.
    sizes: Option<Vec<(usize, usize)>>,
    first_index: u64,
}

/// An input's episodes being made on their own thread and handed over a part at a time (the
/// thread waits until each is taken): `episodes` are to come, the first `skip` dropped.
struct Producing {
    receiver: Option<Receiver<Result<Made, IngestError>>>,
    /// Asks the thread to stop (the source dropped before its last episode).
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
    episodes: usize,
    skip: usize,
    path: PathBuf,
}

impl Producer {
    fn start(self, episodes: usize, skip: usize) -> Producing {
        let (sender, receiver) = sync_channel(0);
        let stop = Arc::new(AtomicBool::new(false));
        let stopping = Arc::clone(&stop);
        let path = self.path.clone();
        // As many workers as the pool this is started from (`--threads`).
        let threads = rayon::current_num_threads();
        let thread = std::thread::spawn(move || {
            let stopped = || IngestError::Stopped;
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build();
            let run = |hand: &mut (dyn FnMut(Option<Made>) -> Result<(), IngestError> + Send)| {
                match &pool {
                    Ok(pool) => pool.install(|| self.run(hand)),
                    Err(_) => self.run(hand),
                }
            };
            let made = run(&mut |made| {
                if stopping.load(Ordering::Relaxed) {
                    return Err(stopped());
                }
                match made {
                    Some(made) => sender.send(Ok(made)).map_err(|_| stopped()),
                    None => Ok(()),
                }
            });
            if let Err(error) = made {
                sender.send(Err(error)).ok();
            }
        });
        Producing {
            receiver: Some(receiver),
            stop,
            thread: Some(thread),
            episodes,
            skip,
            path,
        }
    }

    /// Reads the input again, handing on each episode made (and None after every frame, to
    /// stop early when asked).
    fn run(
        &self,
        hand: &mut (dyn FnMut(Option<Made>) -> Result<(), IngestError> + Send),
    ) -> Result<(), IngestError> {
        let options = &self.options;
        let (topics, plan) = (&self.planned.topics, &self.planned.plan);
        let instructions = topics.last().is_some_and(|t| t.topic == INSTRUCTION_TOPIC);
        let mut making = Making::new(
            &self.path,
            &options.preset,
            (options.task.as_deref(), instructions),
            options.parting,
            options.instruction_text,
            self.sizes.clone(),
            self.first_index,
        );
        let at = BagInput::new(&self.path, options.scratch.as_deref());
        second_pass(at, topics, plan, &self.builtin, &mut |handed| {
            let made = making.take(handed)?;
            hand(made)
        })
    }
}

impl Producing {
    /// The next part to hand on; None after the last episode's last.
    fn next(&mut self) -> Result<Option<Made>, IngestError> {
        loop {
            if self.episodes == 0 {
                return Ok(None);
            }
            let received = self.receiver.as_ref().map(Receiver::recv);
            let made = match received {
                Some(Ok(made)) => made?,
                _ => {
                    return Err(IngestError::ReadingEnded {
                        path: self.path.clone(),
                        episodes: self.episodes,
                    });
                }
            };
            let last = made.part.last;
            if last {
                self.episodes -= 1;
            }
            if self.skip > 0 {
                if last {
                    self.skip -= 1;
                }
                continue;
            }
            return Ok(Some(made));
        }
    }
}

impl Drop for Producing {
    /// Stops the thread (it ends at its next frame, or at once when waiting to hand over an
    /// episode) and waits for it.
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        drop(self.receiver.take());
        if let Some(thread) = self.thread.take() {
            thread.join().ok();
        }
    }
}

/// What a resume compares of an input's content: a file's size; a bag folder's files' names
/// and sizes in name order (a folder entry's own size says nothing of its files; a folder of
/// more than 100,000 entries is compared by its first ones read).
fn content_sizes(path: &Path) -> String {
    let Ok(metadata) = std::fs::metadata(path) else {
        return String::new();
    };
    if !metadata.is_dir() {
        return metadata.len().to_string();
    }
    let mut files: Vec<(String, u64)> = std::fs::read_dir(path)
        .map(|entries| {
            entries
                .flatten()
                .take(100_000)
                .filter_map(|e| {
                    let size = e.metadata().ok().filter(|m| m.is_file())?.len();
                    Some((e.file_name().to_string_lossy().into_owned(), size))
                })
                .collect()
        })
        .unwrap_or_default();
    files.sort();
    (files.iter())
        .map(|(name, size)| format!("{name}:{size}"))
        .collect::<Vec<_>>()
        .join("/")
}

/// The per-frame instruction's feature name (Open-H's).
pub const INSTRUCTION_FEATURE: &str = "instruction.text";

/// Refuses a split that is empty, reaches past the `total` episodes, overlaps another or
/// repeats a name.
fn check_splits(splits: &[(String, std::ops::Range<u64>)], total: u64) -> Result<(), IngestError> {
    for (i, (name, range)) in splits.iter().enumerate() {
        let problem = if range.start >= range.end {
            Some(format!("{}:{} holds no episode", range.start, range.end))
        } else if range.end > total {
            Some(format!(
                "{}:{} reaches past the {total} episodes the inputs make",
                range.start, range.end
            ))
        } else {
            splits[..i].iter().find_map(|(other, earlier)| {
                if other == name {
                    Some("is given twice".to_string())
                } else {
                    (earlier.start < range.end && range.start < earlier.end)
                        .then(|| format!("overlaps {other} ({}:{})", earlier.start, earlier.end))
                }
            })
        };
        if let Some(problem) = problem {
            return Err(IngestError::Usage(format!("--split {name}: {problem}")));
        }
    }
    Ok(())
}

/// The topics of `options`' preset in `path`, read once and planned: the instruction topic is
/// left out when the recording has none; any other topic it lacks is an error.
fn planned(
    path: &Path,
    options: &IngestOptions,
    builtin: &MessageDefs,
) -> Result<Planned, IngestError> {
    let mut topics = options.topics();
    let candidates = options.preset.camera_info_topics();
    let keep: Vec<String> = candidates.iter().flatten().cloned().collect();
    let at = BagInput::new(path, options.scratch.as_deref());
    let mut first = first_pass_keeping(at, &topics, options.clock, builtin, &keep)?;
    // Each camera's first CameraInfo found among its candidates.
    let mut kept = first.first_messages.iter();
    let camera_info = (candidates.iter())
        .map(|topics| {
            let mine: Vec<&Option<_>> = kept.by_ref().take(topics.len()).collect();
            let found = mine.into_iter().flatten().next();
            found.map(camera_intrinsics).unwrap_or_default()
        })
        .collect();
    // The instruction topic is read only when no --task is given, and left out when the
    // recording has none.
    if (options.task.is_some() || first.channels.last().is_some_and(Option::is_none))
        && topics.last().is_some_and(|t| t.topic == INSTRUCTION_TOPIC)
    {
        topics.pop();
        first.channels.pop();
        first.streams.pop();
    }
    if let Some((topic, _)) = (topics.iter())
        .zip(&first.streams)
        .find(|(_, stream)| stream.stamps_ns.is_empty())
    {
        return Err(IngestError::MissingTopic {
            path: path.to_path_buf(),
            topic: topic.topic.clone(),
        });
    }
    let plan = plan(&first.streams, &options.sync).map_err(|source| IngestError::Sync {
        path: path.to_path_buf(),
        source,
    })?;
    Ok(Planned {
        topics,
        plan,
        camera_info,
    })
}

/// Whole episodes: each one's parts gathered (for sinks that take whole episodes, and
/// `--verify`).
impl Iterator for IngestSource {
    type Item = Result<Episode, ExportError>;

    fn next(&mut self) -> Option<Self::Item> {
        let mut gathering = Gathering::default();
        loop {
            let part = match self.next_part()? {
                Ok(part) => part,
                Err(error) => return Some(Err(error)),
            };
            match gathering.take(part) {
                Ok(Some(episode)) => return Some(Ok(episode)),
                Ok(None) => {}
                Err(error) => return Some(Err(error)),
            }
        }
    }
}

impl EpisodeSource for IngestSource {
    fn info(&self) -> &DatasetInfo {
        &self.info
    }

    fn makes_parts(&self) -> bool {
        true
    }

    fn next_part(&mut self) -> Option<Result<EpisodePart, ExportError>> {
        if self.failed {
            return None;
        }
        if let Some(ready) = self.ready.take() {
            return Some(Ok(ready));
        }
        match self.receive() {
            Ok(part) => part.map(Ok),
            Err(error) => {
                self.failed = true;
                Some(Err(ExportError::Input(Box::new(error))))
            }
        }
    }

    /// Skips an episode without reading its messages where a whole input is skipped.
    fn skip_episode(&mut self) -> Option<Result<(), ExportError>> {
        if self.failed {
            return None;
        }
        if self.ready.is_some() || self.producing.as_ref().is_some_and(|p| p.episodes > 0) {
            // The episode being read: its parts up to its last.
            loop {
                match self.next_part()? {
                    Ok(part) if part.last => return Some(Ok(())),
                    Ok(_) => {}
                    Err(error) => return Some(Err(error)),
                }
            }
        }
        self.producing = None;
        let input = self.inputs.get(self.next_input)?;
        self.skipped += 1;
        if self.skipped == input.report.episodes.len() {
            self.next_input += 1;
            self.next_index += self.skipped as u64;
            self.skipped = 0;
        }
        Some(Ok(()))
    }

    fn len(&self) -> u64 {
        self.total
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::episode::FeatureValue;
    use crate::ingest::sync::OnGap;

    /// A little CDR writer (little-endian, aligned from after the 4-byte header).
    struct Cdr(Vec<u8>);

    impl Cdr {
        fn new() -> Cdr {
            Cdr(vec![0, 1, 0, 0])
        }
        fn align(&mut self, n: usize) {
            while !(self.0.len() - 4).is_multiple_of(n) {
                self.0.push(0);
            }
        }
        fn u32(&mut self, v: u32) -> &mut Self {
            self.align(4);
            self.0.extend(v.to_le_bytes());
            self
        }
        fn f64(&mut self, v: f64) -> &mut Self {
            self.align(8);
            self.0.extend(v.to_le_bytes());
            self
        }
        fn string(&mut self, s: &str) -> &mut Self {
            self.u32(s.len() as u32 + 1);
            self.0.extend(s.as_bytes());
            self.0.push(0);
            self
        }
        fn header(&mut self, ns: i64) -> &mut Self {
            self.u32((ns / 1_000_000_000) as u32)
                .u32((ns % 1_000_000_000) as u32)
                .string("world")
        }
    }

    fn pose(ns: i64, x: f64) -> Vec<u8> {
        let mut c = Cdr::new();
        c.header(ns);
        for v in [x, 0.5, -0.25, 0.0, 0.0, 0.0, 1.0] {
            c.f64(v);
        }
        c.0
    }

    fn jaw(ns: i64, angle: f64) -> Vec<u8> {
        let mut c = Cdr::new();
        c.header(ns)
            .u32(1)
            .string("jaw")
            .u32(1)
            .f64(angle)
            .u32(0)
            .u32(0);
        c.0
    }

    fn image(ns: i64, value: u8, (width, height): (u32, u32)) -> Vec<u8> {
        let mut c = Cdr::new();
        c.header(ns).u32(height).u32(width).string("rgb8");
        c.0.push(0);
        let bytes = width * height * 3;
        c.u32(width * 3).u32(bytes);
        (c.0).extend(std::iter::repeat_n(value, bytes as usize));
        c.0
    }

    /// A recording: arm at 100 Hz, camera at 10 Hz, setpoints at 50 Hz, for 1 s (no schema:
    /// the built-in definitions).
    fn recording() -> PathBuf {
        crate::ingest::fixtures::temp_file("ingest.mcap", &recording_bytes(SMALL))
    }

    /// The bytes of [`recording`].
    /// The camera's (width, height) in most tests.
    const SMALL: (u32, u32) = (3, 2);

    /// The bytes of [`recording`], the camera's images `size` (width, height).
    fn recording_bytes(size: (u32, u32)) -> Vec<u8> {
        let channels = [
            ("/PSM1/measured_cp", "geometry_msgs/msg/PoseStamped", ""),
            ("/PSM1/jaw/measured_js", "sensor_msgs/msg/JointState", ""),
            ("/PSM1/setpoint_cp", "geometry_msgs/msg/PoseStamped", ""),
            ("/PSM1/jaw/setpoint_js", "sensor_msgs/msg/JointState", ""),
            ("/camera/left", "sensor_msgs/msg/Image", ""),
            ("/ECM/measured_cp", "geometry_msgs/msg/PoseStamped", ""),
        ];
        let mut messages: Vec<(usize, u64, Vec<u8>)> = Vec::new();
        let ms = 1_000_000i64;
        for k in 0..100 {
            let t = 1_000_000_000 + k * 10 * ms;
            messages.push((0, t as u64, pose(t, k as f64)));
            messages.push((1, t as u64, jaw(t, k as f64 / 100.0)));
            if k % 2 == 0 {
                messages.push((2, t as u64, pose(t, k as f64 + 0.5)));
                messages.push((3, t as u64, jaw(t, 0.75)));
            }
            if k % 10 == 0 {
                messages.push((4, t as u64, image(t, k as u8, size)));
            }
            messages.push((5, t as u64, pose(t, -(k as f64))));
        }
        crate::ingest::fixtures::mcap_bytes(None, &channels, &messages)
    }

    /// [`recording`] with an instruction topic that moves on at 1.45 s.
    fn recording_with_instructions() -> PathBuf {
        rewritten(true, &[], SMALL)
    }

    /// [`recording`] with the instruction topic when `instructions`, without the camera's
    /// messages at `drop_ns`.
    fn rewritten(instructions: bool, drop_ns: &[u64], size: (u32, u32)) -> PathBuf {
        let bytes = recording_bytes(size);
        let mut channels: Vec<(&str, &str, &str)> = [
            ("/PSM1/measured_cp", "geometry_msgs/msg/PoseStamped"),
            ("/PSM1/jaw/measured_js", "sensor_msgs/msg/JointState"),
            ("/PSM1/setpoint_cp", "geometry_msgs/msg/PoseStamped"),
            ("/PSM1/jaw/setpoint_js", "sensor_msgs/msg/JointState"),
            ("/camera/left", "sensor_msgs/msg/Image"),
            ("/ECM/measured_cp", "geometry_msgs/msg/PoseStamped"),
        ]
        .map(|(topic, kind)| (topic, kind, ""))
        .to_vec();
        let mut messages: Vec<(usize, u64, Vec<u8>)> = Vec::new();
        for message in mcap::MessageStream::new(&bytes).expect("mcap") {
            let message = message.expect("message");
            let at = (channels.iter())
                .position(|c| c.0 == message.channel.topic)
                .expect("a known topic");
            if at == 4 && drop_ns.contains(&message.log_time) {
                continue;
            }
            messages.push((at, message.log_time, message.data.to_vec()));
        }
        if instructions {
            channels.push(("/instruction", "std_msgs/msg/String", ""));
            let string = crate::ingest::fixtures::cdr_string;
            messages.push((6, 900_000_000, string("grasp the needle")));
            messages.push((6, 1_450_000_000, string("pass the needle")));
        }
        messages.sort_by_key(|m| m.1);
        let bytes = crate::ingest::fixtures::mcap_bytes(None, &channels, &messages);
        let name = format!("rewritten-{instructions}-{}.mcap", drop_ns.len());
        crate::ingest::fixtures::temp_file(&name, &bytes)
    }

    #[test]
    fn an_instruction_that_moves_on_gives_per_step_tasks_in_every_format() {
        let path = recording_with_instructions();
        let options = IngestOptions {
            task: None,
            ..options()
        };
        let mut source = IngestSource::open(std::slice::from_ref(&path), options).expect("open");
        let info = source.info().clone();
        let episode = source.next().expect("an episode").expect("read");
        // Frames at 1.0 .. 1.9 s: 1.0 .. 1.4 s hold the first instruction, 1.5 s on the second.
        assert_eq!(episode.meta.instruction, "grasp the needle");
        let changes = &episode.meta.task_changes;
        assert_eq!(changes.len(), 1);
        assert_eq!(
            (changes[0].first_step, changes[0].instruction.as_str()),
            (5, "pass the needle")
        );
        assert_eq!(episode.meta.instruction_at(4), "grasp the needle");
        assert_eq!(episode.meta.instruction_at(9), "pass the needle");
        for format in ["lerobot", "rlds"] {
            let out =
                std::env::temp_dir().join(format!("surgvla-tasks-{format}-{}", std::process::id()));
            std::fs::remove_dir_all(&out).ok();
            let mut sink: Box<dyn crate::export::EpisodeSink + Send> = if format == "lerobot" {
                use crate::export::lerobot::{LeRobotOptions, LeRobotWriter};
                LeRobotWriter::boxed(&out, &info, LeRobotOptions::default(), false).expect("sink")
            } else {
                use crate::export::rlds::{RldsOptions, RldsWriter};
                RldsWriter::boxed(&out, &info, RldsOptions::default(), false).expect("sink")
            };
            sink.write_batch(std::slice::from_ref(&episode))
                .expect("write");
            sink.finish().expect("finish");
            let fps = crate::export::source::SourceOptions {
                fps: Some(10),
                ..Default::default()
            };
            let mut back = crate::export::open::open_source_with(&out, &fps).expect("read back");
            let read = back.next().expect("an episode").expect("read");
            assert_eq!(read.meta.instruction, episode.meta.instruction, "{format}");
            assert_eq!(
                read.meta.task_changes, episode.meta.task_changes,
                "{format}"
            );
            std::fs::remove_dir_all(out).ok();
        }
        std::fs::remove_file(path).ok();
    }

    /// Every file of the dataset in `dir` but its data parquet (which a part writes as a row
    /// group of its own) and the card, by relative path.
    fn files_but_data(dir: &Path) -> Vec<(String, Vec<u8>)> {
        let mut files = Vec::new();
        let mut stack = vec![dir.to_path_buf()];
        while let Some(at) = stack.pop() {
            for entry in std::fs::read_dir(&at).expect("read dir").flatten() {
                let path = entry.path();
                let name = path
                    .strip_prefix(dir)
                    .expect("inside")
                    .to_string_lossy()
                    .into_owned();
                if path.is_dir() {
                    stack.push(path);
                } else if !name.starts_with("data/") && !name.ends_with("manifest.json") {
                    files.push((name, std::fs::read(&path).expect("read")));
                }
            }
        }
        files.sort();
        files
    }

    #[test]
    fn a_long_episode_is_written_in_parts_and_reads_back_as_the_whole_one() {
        use crate::export::lerobot::{LeRobotOptions, LeRobotWriter};
        // A camera of a size video encoders take.
        let path = rewritten(true, &[], (32, 16));
        let whole_options = IngestOptions {
            task: None,
            ..options()
        };
        // Parts of two frames: the instruction moves on inside the third.
        let parted = IngestOptions {
            parting: Parting {
                batch_frames: 2,
                part_bytes: 1,
            },
            ..whole_options.clone()
        };
        let mut source =
            IngestSource::open(std::slice::from_ref(&path), parted.clone()).expect("open");
        let mut parts = Vec::new();
        while let Some(part) = source.next_part() {
            let part = part.expect("read");
            parts.push((part.first_step, part.episode.steps.len(), part.last));
        }
        assert_eq!(
            parts,
            [
                (0, 2, false),
                (2, 2, false),
                (4, 2, false),
                (6, 2, false),
                (8, 2, true)
            ]
        );
        let mut source =
            IngestSource::open(std::slice::from_ref(&path), whole_options).expect("open");
        let whole = source.next().expect("an episode").expect("read");
        let mut gathered =
            IngestSource::open(std::slice::from_ref(&path), parted.clone()).expect("open");
        assert_eq!(
            gathered.next().expect("an episode").expect("read"),
            whole,
            "gathered"
        );
        for video in [None, Some("av1")] {
            let lerobot = LeRobotOptions {
                video: video.map(|_| crate::export::lerobot::VideoOptions::default()),
                ..LeRobotOptions::default()
            };
            let mut written = Vec::new();
            for (name, options) in [("whole", options_whole(&parted)), ("parts", parted.clone())] {
                let out = std::env::temp_dir().join(format!(
                    "surgvla-parts-{name}-{}-{}",
                    video.is_some(),
                    std::process::id()
                ));
                std::fs::remove_dir_all(&out).ok();
                let mut source =
                    IngestSource::open(std::slice::from_ref(&path), options).expect("open");
                let info = source.info().clone();
                let mut sink =
                    LeRobotWriter::boxed(&out, &info, lerobot.clone(), false).expect("sink");
                crate::export::convert::convert(&mut source, sink.as_mut(), 2, &mut |_| {})
                    .expect("convert");
                let mut back = crate::export::open::open_source(&out).expect("read back");
                let read = back.next().expect("an episode").expect("read");
                assert_eq!(read.meta.task_changes, whole.meta.task_changes, "{name}");
                assert_eq!(read.steps.len(), whole.steps.len(), "{name}");
                if video.is_none() {
                    for (a, b) in read.steps.iter().zip(&whole.steps) {
                        assert_eq!(a.other, b.other, "{name}");
                    }
                }
                written.push(files_but_data(&out));
                std::fs::remove_dir_all(out).ok();
            }
            // Statistics, episodes table, tasks, info and videos: the same bytes.
            assert!(written[0] == written[1], "video {video:?}");
        }
        std::fs::remove_file(path).ok();
    }

    /// `options` with parts too large to come before an episode's end.
    fn options_whole(options: &IngestOptions) -> IngestOptions {
        IngestOptions {
            parting: Parting {
                batch_frames: 2,
                part_bytes: usize::MAX,
            },
            ..options.clone()
        }
    }

    #[test]
    fn image_statistics_carried_from_the_pixels_equal_those_of_the_decoded_images() {
        use crate::export::lerobot::{LeRobotOptions, LeRobotWriter};
        let path = recording();
        let mut source = IngestSource::open(std::slice::from_ref(&path), options()).expect("open");
        let info = source.info().clone();
        let carried = source.next().expect("an episode").expect("read");
        assert_eq!(carried.image_stats.len(), 1, "the camera's");
        assert_eq!(carried.image_stats[0].0, "observation.images.left");
        let decoded = Episode {
            image_stats: Vec::new(),
            stored_rows: None,
            ..carried.clone()
        };
        let mut written = Vec::new();
        for (name, episode) in [("carried", &carried), ("decoded", &decoded)] {
            let out =
                std::env::temp_dir().join(format!("surgvla-carried-{name}-{}", std::process::id()));
            std::fs::remove_dir_all(&out).ok();
            let mut sink =
                LeRobotWriter::boxed(&out, &info, LeRobotOptions::default(), false).expect("sink");
            sink.write_batch(std::slice::from_ref(episode))
                .expect("write");
            sink.finish().expect("finish");
            let stats = std::fs::read(out.join("meta/stats.json")).expect("stats");
            let episodes = out.join("meta/episodes/chunk-000/file-000.parquet");
            written.push((stats, std::fs::read(episodes).expect("episodes")));
            std::fs::remove_dir_all(out).ok();
        }
        assert!(
            written[0] == written[1],
            "the same statistics, byte for byte"
        );
        std::fs::remove_file(path).ok();
    }

    #[test]
    fn episodes_come_one_at_a_time_across_inputs_and_a_source_dropped_midway_stops() {
        let path = recording();
        let inputs = [path.clone(), path.clone(), path.clone()];
        let mut source = IngestSource::open(&inputs, options()).expect("open");
        assert_eq!(source.len(), 3);
        // The first input's episode is made when the source opens; the second is skipped
        // (a resume); the third is made on its own thread.
        assert!(matches!(source.skip_episode(), Some(Ok(()))));
        assert!(matches!(source.skip_episode(), Some(Ok(()))));
        let third = source.next().expect("an episode").expect("read");
        assert_eq!((third.meta.index, third.steps.len()), (2, 10));
        assert!(source.next().is_none());
        // A recording of two episodes (the camera's 1.4 and 1.5 s images missing: the 1.5 s
        // frame's newest image is older than the tolerance): dropped while its
        // reading thread waits to hand over the second, the source stops it (no hang).
        let gap = rewritten(false, &[1_400_000_000, 1_500_000_000], SMALL);
        let source = IngestSource::open(std::slice::from_ref(&gap), options()).expect("open");
        assert_eq!(source.len(), 2);
        let (dropped, done) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            drop(source);
            dropped.send(()).ok();
        });
        let waited = done.recv_timeout(std::time::Duration::from_secs(60));
        assert!(waited.is_ok(), "dropping the source hangs");
        let mut source = IngestSource::open(std::slice::from_ref(&gap), options()).expect("open");
        let lengths: Vec<usize> = (source.by_ref())
            .map(|e| e.expect("read").steps.len())
            .collect();
        assert_eq!(lengths, [5, 4], "1.0-1.4 s, then 1.6-1.9 s");
        std::fs::remove_file(path).ok();
        std::fs::remove_file(gap).ok();
    }

    /// One arm, the left camera, 10 fps, split at gaps, a given task.
    fn options() -> IngestOptions {
        IngestOptions {
            preset: DvrkPreset::new(&["PSM1".into()], &[("left".into(), "/camera/left".into())]),
            clock: Clock::Header,
            sync: SyncOptions {
                on_gap: OnGap::Split,
                ..SyncOptions::at(10)
            },
            task: Some("cut the suture".into()),
            offsets_ns: Vec::new(),
            instruction_text: false,
            splits: Vec::new(),
            scratch: None,
            parting: Parting::default(),
        }
    }

    #[test]
    fn mapped_topics_become_features_after_the_action() {
        let path = recording();
        let mut mapped = options();
        let map = "[[feature]]\nname = \"observation.meta.ecm_pose\"\ntopic = \"/ECM/measured_cp\"\nvalues = \"pose\"\n";
        let features = crate::ingest::map::parse(map).expect("map");
        mapped.preset = mapped.preset.with_mapped(features);
        let mut source =
            IngestSource::open(std::slice::from_ref(&path), mapped.clone()).expect("open");
        let info = source.info().clone();
        let ecm = &info.features[3];
        assert_eq!(
            (ecm.name.as_str(), ecm.shape.as_slice()),
            ("observation.meta.ecm_pose", &[7][..])
        );
        assert_eq!(ecm.info["ros.topic"], "/ECM/measured_cp");
        assert_eq!(
            info.features[1].info["PSM1.frame_id"], "world",
            "the poses' frame"
        );
        let episode = source.next().expect("an episode").expect("read");
        for (k, step) in episode.steps.iter().enumerate() {
            let Some(FeatureValue::Float32(values)) = step.other.get(3) else {
                panic!("the ECM's pose after the action");
            };
            assert_eq!(values[..3], [-((10 * k) as f32), 0.5, -0.25], "frame {k}");
        }
        // A topic read twice is refused before the recording is read.
        let mut twice = mapped;
        twice.preset.mapped[0].topic = "/camera/left".into();
        let error = IngestSource::open(std::slice::from_ref(&path), twice).err();
        assert!(error.is_some_and(|e| e.to_string().contains("/camera/left is read twice")));
        std::fs::remove_file(path).ok();
    }

    #[test]
    fn splits_are_checked_against_the_episodes_made() {
        let split = |name: &str, range: std::ops::Range<u64>| (name.to_string(), range);
        assert!(check_splits(&[split("train", 0..8), split("recovery", 8..10)], 10).is_ok());
        for (splits, problem) in [
            (vec![split("train", 0..11)], "reaches past the 10 episodes"),
            (vec![split("train", 4..4)], "holds no episode"),
            (
                vec![split("train", 0..5), split("val", 4..6)],
                "overlaps train (0:5)",
            ),
            (
                vec![split("train", 0..5), split("train", 5..6)],
                "is given twice",
            ),
        ] {
            let error = check_splits(&splits, 10).expect_err(problem).to_string();
            assert!(error.contains(problem), "{error}");
        }
    }

    #[test]
    fn each_frame_carries_its_instruction_as_text_when_asked() {
        let path = recording();
        let mut with_text = options();
        with_text.instruction_text = true;
        with_text.splits = vec![("train".into(), 0..1)];
        let mut source = IngestSource::open(std::slice::from_ref(&path), with_text).expect("open");
        let info = source.info().clone();
        let text = info.features.last().expect("features");
        assert_eq!(
            (text.name.as_str(), text.dtype),
            (INSTRUCTION_FEATURE, Dtype::String)
        );
        assert_eq!(info.splits, [("train".to_string(), 0..1)]);
        let episode = source.next().expect("an episode").expect("read");
        for step in &episode.steps {
            assert_eq!(
                step.other.last(),
                Some(&FeatureValue::Text("cut the suture".into()))
            );
        }
        // A split past the episodes made is refused when the source opens.
        let mut too_far = options();
        too_far.splits = vec![("val".into(), 1..2)];
        let error = IngestSource::open(std::slice::from_ref(&path), too_far).err();
        assert!(error.is_some_and(|e| e.to_string().contains("reaches past")));
        std::fs::remove_file(path).ok();
    }

    #[test]
    fn a_dvrk_recording_becomes_episodes_of_the_rules_messages() {
        let path = recording();
        let mut source = IngestSource::open(std::slice::from_ref(&path), options()).expect("open");
        assert_eq!(source.len(), 1);
        let info = source.info().clone();
        assert_eq!(info.fps, 10);
        assert_eq!(info.features[0].shape, [2, 3, 3], "height 2, width 3");
        assert!(!info.is_ours(), "the robot's episodes, not surgvla's");
        let names: Vec<&str> = info.features.iter().map(|f| f.name.as_str()).collect();
        assert_eq!(
            names,
            ["observation.images.left", "observation.state", "action"]
        );
        let episode = source.next().expect("an episode").expect("read");
        assert!(source.next().is_none());
        assert_eq!(episode.meta.instruction, "cut the suture");
        // The grid: the camera's 1.0 s .. 1.9 s; frame k at 1.0 + 0.1 k s takes arm message 10 k.
        assert_eq!(episode.steps.len(), 10);
        for (k, step) in episode.steps.iter().enumerate() {
            let [
                FeatureValue::Image(png),
                FeatureValue::Float32(state),
                FeatureValue::Float32(action),
            ] = &step.other[..]
            else {
                panic!("an image, the state and the action");
            };
            assert_eq!(state[0], (10 * k) as f32, "frame {k}");
            assert_eq!(state[7], (10 * k) as f32 / 100.0);
            assert_eq!(action[0], (10 * k) as f32 + 0.5);
            let pixels = crate::media::image::decode_png(png).expect("png").3;
            assert_eq!(pixels, vec![(10 * k) as u8; 18]);
        }
        assert_eq!(source.reports().len(), 1);
        std::fs::remove_file(path).ok();
    }

    #[test]
    fn ingested_episodes_write_as_a_lerobot_dataset_that_reads_back() {
        use crate::export::lerobot::{LeRobotOptions, LeRobotWriter};
        let path = recording();
        let mut source = IngestSource::open(std::slice::from_ref(&path), options()).expect("open");
        let out = std::env::temp_dir().join(format!("surgvla-ingested-{}", std::process::id()));
        std::fs::remove_dir_all(&out).ok();
        let mut sink = LeRobotWriter::boxed(&out, source.info(), LeRobotOptions::default(), false)
            .expect("sink");
        let summary = crate::export::convert::convert(&mut source, sink.as_mut(), 1, &mut |_| {})
            .expect("convert");
        assert_eq!((summary.episodes, summary.frames), (1, 10));
        let mut back = crate::export::lerobot::read::LeRobotSource::open(&out).expect("read back");
        let episode = back.next().expect("an episode").expect("read");
        assert_eq!(episode.meta.instruction, "cut the suture");
        let [FeatureValue::Image(png), FeatureValue::Float32(state), _] =
            &episode.steps[3].other[..]
        else {
            panic!("an image, the state and the action");
        };
        assert_eq!(state[0], 30.0);
        let pixels = crate::media::image::decode_png(png).expect("png").3;
        assert_eq!(pixels, vec![30u8; 18]);
        std::fs::remove_file(path).ok();
        std::fs::remove_dir_all(out).ok();
    }
}
