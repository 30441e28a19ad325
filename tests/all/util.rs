//! Helpers shared by the integration tests.

use nalgebra::{Isometry3, Translation3};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use surgvla::sim::psm::pointing_down;
use surgvla::sim::{SceneSpec, SimConfig, Simulator};

/// A scene with one object of each kind, resting on the tray (or `drop_m` above it).
pub(crate) fn three_objects(drop_m: f64) -> SceneSpec {
    SceneSpec::one_of_each(drop_m)
}

pub(crate) fn simulator(scene: SceneSpec) -> Simulator {
    Simulator::new(SimConfig::default(), scene)
}

/// A pointing-down tip pose.
pub(crate) fn tip_at(x: f64, y: f64, z: f64, yaw_rad: f64) -> Isometry3<f64> {
    Isometry3::from_parts(Translation3::new(x, y, z), pointing_down(yaw_rad))
}

/// A fresh, unique temporary folder path (not created), removed with everything under it when
/// the guard drops, also when the test fails: a failing test must not leave datasets behind.
pub(crate) fn temp_root(name: &str) -> TempRoot {
    static COUNTER: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
    let n = COUNTER.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
    TempRoot(std::env::temp_dir().join(format!("surgvla-{name}-{}-{n}", std::process::id())))
}

/// The folder (not created) of a dataset the tests of one module share, made once and held in
/// a static. A static is never dropped, so a [`TempRoot`] there would outlive every run: this
/// one lives in Cargo's scratch folder for integration tests (`target/tmp`), named by the
/// run's process, and the runs that ended (their process gone) leave theirs to be removed by
/// the next one that asks for the same name.
pub(crate) fn shared_root(name: &str) -> PathBuf {
    let scratch = Path::new(env!("CARGO_TARGET_TMPDIR"));
    let prefix = format!("surgvla-{name}-");
    for entry in std::fs::read_dir(scratch).into_iter().flatten().flatten() {
        let file = entry.file_name();
        let ended = (file.to_str())
            .and_then(|file| file.strip_prefix(&prefix))
            .and_then(|pid| pid.parse::<u32>().ok())
            .is_some_and(|pid| !Path::new(&format!("/proc/{pid}")).exists());
        if ended {
            std::fs::remove_dir_all(entry.path()).ok();
        }
    }
    scratch.join(format!("{prefix}{}", std::process::id()))
}

#[test]
fn a_shared_root_removes_those_of_ended_runs_only() {
    let scratch = Path::new(env!("CARGO_TARGET_TMPDIR"));
    // No process has this number (Linux's pids stop at 2^22).
    let ended = scratch.join(format!("surgvla-sweep-test-{}", u32::MAX));
    let running = scratch.join(format!("surgvla-sweep-test-{}", std::process::id()));
    let other = scratch.join(format!("surgvla-sweep-other-{}", u32::MAX));
    for dir in [&ended, &running, &other] {
        std::fs::create_dir_all(dir.join("data")).expect("mkdir");
    }
    assert_eq!(shared_root("sweep-test"), running);
    assert!(!ended.exists(), "an ended run's folder stays");
    assert!(
        running.exists() && other.exists(),
        "a live or other folder went"
    );
    for dir in [&running, &other] {
        std::fs::remove_dir_all(dir).expect("clean up");
    }
}

/// See [`temp_root`].
#[derive(Debug)]
pub(crate) struct TempRoot(PathBuf);

impl std::ops::Deref for TempRoot {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<Path> for TempRoot {
    fn as_ref(&self) -> &Path {
        &self.0
    }
}

impl Drop for TempRoot {
    fn drop(&mut self) {
        std::fs::remove_dir_all(&self.0).ok();
    }
}

/// Every file under `root`: relative path -> bytes.
pub(crate) fn tree(root: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut files = BTreeMap::new();
    let mut pending = vec![root.to_path_buf()];
    while let Some(dir) = pending.pop() {
        for entry in std::fs::read_dir(&dir).expect("read dir") {
            let path = entry.expect("entry").path();
            if path.is_dir() {
                pending.push(path);
            } else {
                let relative = path.strip_prefix(root).expect("prefix");
                let bytes = std::fs::read(&path).expect("read");
                files.insert(relative.to_string_lossy().into_owned(), bytes);
            }
        }
    }
    files
}

/// Runs the `surgvla` binary: (exit code, stdout, stderr).
pub(crate) fn surgvla(args: &[&str]) -> (i32, String, String) {
    let output = std::process::Command::new(env!("CARGO_BIN_EXE_surgvla"))
        .args(args)
        .output()
        .expect("run surgvla");
    (
        output.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&output.stdout).into_owned(),
        String::from_utf8_lossy(&output.stderr).into_owned(),
    )
}

/// The dataset info of a default collection (`with_mask`: plus the mask feature).
pub(crate) fn info(with_mask: bool) -> surgvla::export::DatasetInfo {
    let features = surgvla::episode::FeatureSet {
        mask: with_mask,
        ..Default::default()
    };
    surgvla::collect::run::dataset_info(
        &surgvla::collect::run::CollectOptions::default(),
        features,
        &surgvla::policy::ExpertLibrary::builtin().expect("plans"),
    )
}

/// A dataset another tool made: a 14-D float vector, a one-value int64 and a camera's PNG,
/// all `FeatureKind::Other`, no generator; three episodes of seeded values.
pub(crate) fn foreign_dataset() -> (surgvla::export::DatasetInfo, Vec<surgvla::episode::Episode>) {
    use surgvla::episode::{Dtype, EpisodeMeta, FeatureKind, FeatureSpec, FeatureValue, Step};
    use surgvla::media::image::{PngLevel, encode_png};
    let spec = |name: &str, dtype, shape: Vec<usize>| FeatureSpec {
        name: name.into(),
        dtype,
        shape,
        names: Vec::new(),
        kind: FeatureKind::Other,
        video: None,
        info: Default::default(),
    };
    let mut dataset = info(false);
    dataset.features = vec![
        spec("observation.state", Dtype::Float32, vec![14]),
        spec("observation.gripper_count", Dtype::Int64, vec![1]),
        spec("observation.images.wrist", Dtype::Image, vec![8, 10, 3]),
        spec("instruction.text", Dtype::String, vec![1]),
    ];
    // A feature's own facts travel with it.
    dataset.features[0]
        .info
        .insert("frame_id".into(), serde_json::json!("PSM1_base"));
    dataset.generator = String::new();
    dataset.collection = None;
    let mut rng = surgvla::rng::SplitMix64::stream(3, "other-features");
    let episodes: Vec<surgvla::episode::Episode> = (0..3u64)
        .map(|index| surgvla::episode::Episode {
            encoded: Vec::new(),
            image_stats: Vec::new(),
            stored_rows: None,
            meta: EpisodeMeta {
                index,
                task_code: String::new(),
                task_name: String::new(),
                level: 0,
                instruction: format!("task {}", index % 2),
                seed: 0,
                attempts: 1,
                success: true,
                task_changes: Vec::new(),
                fields: serde_json::Map::new(),
            },
            steps: (0..4 + index)
                .map(|k| {
                    let pixels: Vec<u8> = (0..8 * 10 * 3).map(|_| rng.next_u64() as u8).collect();
                    Step {
                        other: vec![
                            FeatureValue::Float32(
                                (0..14)
                                    .map(|_| (rng.next_u64() % 1000) as f32 / 7.0)
                                    .collect(),
                            ),
                            FeatureValue::Int64(vec![(rng.next_u64() % 5) as i64]),
                            FeatureValue::Image(
                                encode_png(10, 8, 3, &pixels, PngLevel::Best).expect("png"),
                            ),
                            FeatureValue::Text(format!("step {k} of task {}", index % 2)),
                        ],
                        ..Step::empty()
                    }
                })
                .collect(),
        })
        .collect();
    (dataset, episodes)
}

/// Runs the binary with `args`, writing into `root`, and kills it once its marker holds a
/// checkpoint (fails the test if none comes within two minutes).
pub(crate) fn kill_after_checkpoint(args: &[&str], root: &Path) {
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_surgvla"))
        .args(args)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("spawn");
    // The marker holds the last checkpoint once one was saved.
    let marker = root.join(surgvla::export::INCOMPLETE_MARKER);
    let checkpointed =
        || std::fs::read_to_string(&marker).is_ok_and(|text| text.contains("\"checkpoint\":{"));
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(120);
    while !checkpointed() && std::time::Instant::now() < deadline {
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    child.kill().expect("kill");
    child.wait().expect("wait");
    assert!(checkpointed(), "no checkpoint within the deadline");
}

/// Runs `open` again while it finds the folder locked, for up to a second: a dropped writer's
/// folder lock can outlive it for an instant, because a child process another test thread
/// forks before its exec shares the lock's file description (that child is this test process's,
/// so the wait is short).
pub(crate) fn unless_briefly_locked<T>(
    mut open: impl FnMut() -> Result<T, surgvla::export::ExportError>,
) -> Result<T, surgvla::export::ExportError> {
    let mut attempt = open();
    for _ in 0..50 {
        if !matches!(attempt, Err(surgvla::export::ExportError::Locked { .. })) {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
        attempt = open();
    }
    attempt
}

/// A PNG's pixels (RGB, as the charts are written) and its width.
pub(crate) fn png_rgb(path: &Path) -> (Vec<u8>, usize) {
    let file = std::io::BufReader::new(std::fs::File::open(path).expect("png"));
    let mut reader = png::Decoder::new(file).read_info().expect("png header");
    let mut pixels = vec![0; reader.output_buffer_size().expect("size")];
    let info = reader.next_frame(&mut pixels).expect("png frame");
    pixels.truncate(info.buffer_size());
    (pixels, info.width as usize)
}
