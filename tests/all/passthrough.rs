//! Encoded bytes passing through unchanged: video-mode LeRobot datasets convert between the
//! v3.0 and v2.1 layouts and merge from shards without decoding or encoding a frame (each
//! equals the dataset collected directly, byte for byte), their statistics stay exact, formats
//! that need pixels refuse video by name, a damaged MP4 is named; PNG and TIFF images are
//! copied as they were stored rather than encoded again.

use crate::util::{info, surgvla, temp_root, tree};
use std::collections::BTreeMap;
use std::path::Path;
use surgvla::episode::{EncodedFeature, EncodedFrame, ImageEncoding};
use surgvla::export::EpisodeSink;
use surgvla::export::lerobot::read::{data_files, read_parquet};
use surgvla::export::lerobot::{LeRobotOptions, LeRobotWriter};
use surgvla::media::image::{PngLevel, encode_png};

const SMALL: [&str; 6] = [
    "--tasks",
    "T1-1,T3-1",
    "--episodes-per-task",
    "2",
    "--video",
    "h264",
];

fn path(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

fn run(args: &[&str]) -> String {
    let (code, stdout, err) = surgvla(args);
    assert_eq!(code, 0, "{args:?}: {err}");
    stdout
}

fn collect(out: &Path, extra: &[&str]) {
    let mut args = vec!["collect", "--out", path(out)];
    args.extend(SMALL);
    args.extend(extra);
    run(&args);
}

/// Every file but the collect report (timings) and the manifest (its options digest records
/// the encoder's quality setting, which a copy of the frames does not know); the manifest's
/// file list with checksums is kept.
fn dataset(root: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut files = tree(root);
    files.remove("collect_report.json");
    if let Some(manifest) = files.remove("meta/surgvla_manifest.json") {
        let json: serde_json::Value = serde_json::from_slice(&manifest).expect("manifest");
        files.insert(
            "manifest files".into(),
            json["files"].to_string().into_bytes(),
        );
    }
    files
}

fn assert_same(a: &BTreeMap<String, Vec<u8>>, b: &BTreeMap<String, Vec<u8>>, what: &str) {
    assert_eq!(
        a.keys().collect::<Vec<_>>(),
        b.keys().collect::<Vec<_>>(),
        "{what}"
    );
    for (name, bytes) in a {
        assert!(b[name] == *bytes, "{what}: {name} differs");
    }
}

#[test]
fn video_converts_between_layouts_and_merges_byte_for_byte() {
    let single = temp_root("pass-single");
    collect(&single, &[]);
    let expected = dataset(&single);
    let direct21 = temp_root("pass-direct21");
    collect(&direct21, &["--lerobot-version", "2.1"]);
    // v3.0 -> v2.1 equals the v2.1 collection; back to v3.0 equals the original.
    let v21 = temp_root("pass-v21");
    let stdout = run(&[
        "convert",
        path(&single),
        "--to",
        "lerobot",
        "--lerobot-version",
        "2.1",
        "--out",
        path(&v21),
        "--verify",
    ]);
    assert!(stdout.contains("verified"), "{stdout}");
    assert_same(&dataset(&direct21), &dataset(&v21), "v2.1");
    let v30 = temp_root("pass-v30");
    run(&[
        "convert",
        path(&v21),
        "--to",
        "lerobot",
        "--out",
        path(&v30),
    ]);
    assert_same(&expected, &dataset(&v30), "v3.0 again");
    // Shards merged equal the single run: video, statistics, metadata.
    for n in [2u32, 3] {
        let shards: Vec<_> = (0..n)
            .map(|i| {
                let shard = temp_root("pass-shard");
                collect(&shard, &["--shard", &format!("{i}/{n}")]);
                shard
            })
            .collect();
        let out = temp_root("pass-merged");
        let mut args = vec!["merge"];
        args.extend(shards.iter().rev().map(|s| path(s)));
        args.extend(["--out", path(&out)]);
        run(&args);
        assert_same(&expected, &dataset(&out), &format!("N = {n}"));
        let (code, _, err) = surgvla(&["validate", path(&out)]);
        assert_eq!(code, 0, "{err}");
    }
    // The exact statistics accumulator travels in the episodes table.
    let table = &read_parquet(&single.join("meta/episodes/chunk-000/file-000.parquet"))
        .expect("episodes")[0];
    assert!(
        table
            .column_by_name("surgvla/pixel_stats/observation.images.endoscope")
            .is_some()
    );
}

#[test]
fn video_is_decoded_where_pixels_are_needed_and_a_damaged_mp4_is_named() {
    let single = temp_root("pass-refuse");
    collect(&single, &[]);
    // Every format that needs pixels gets them decoded; the frames read back are the ones
    // decoded from the video (--verify compares every frame).
    for to in ["rlds", "zarr", "mcap", "ply"] {
        let out = temp_root("pass-decoded");
        let (code, _, err) = surgvla(&[
            "convert",
            path(&single),
            "--to",
            to,
            "--out",
            path(&out),
            "--verify",
        ]);
        assert_eq!(code, 0, "{to}: {err}");
    }
    // Another codec than the video's: decoded and encoded again, verified within the lossy
    // tolerance; image mode on request.
    for (args, codec) in [
        (&["--video", "av1"][..], Some("av1")),
        (&["--decode"][..], None),
    ] {
        let out = temp_root("pass-codec");
        let mut command = vec![
            "convert",
            path(&single),
            "--to",
            "lerobot",
            "--out",
            path(&out),
        ];
        command.extend(args);
        command.push("--verify");
        let (code, _, err) = surgvla(&command);
        assert_eq!(code, 0, "{args:?}: {err}");
        let info: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(out.join("meta/info.json")).expect("info"),
        )
        .expect("json");
        let camera = &info["features"]["observation.images.endoscope"];
        match codec {
            Some(codec) => assert_eq!(camera["info"]["video.codec"], codec),
            None => assert_eq!(camera["dtype"], "image"),
        }
    }
    // A truncated MP4: exit 1 naming it.
    let mp4 = single.join("videos/observation.images.endoscope/chunk-000/file-000.mp4");
    let bytes = std::fs::read(&mp4).expect("mp4");
    std::fs::write(&mp4, &bytes[..bytes.len() / 2]).expect("truncate");
    for to in ["lerobot", "rlds"] {
        let out = temp_root("pass-damaged");
        let (code, _, err) = surgvla(&["convert", path(&single), "--to", to, "--out", path(&out)]);
        assert_eq!(code, 1, "{err}");
        assert!(err.contains("file-000.mp4"), "{err}");
    }
}

#[test]
fn stored_png_bytes_are_copied_not_encoded_again() {
    // A frame whose stored PNG was made at another compression level: the pixels are the same,
    // the bytes are not what this writer would make, and they are what it writes.
    let dataset_info = info(false);
    let mut episode = crate::util::foreign_dataset().1.remove(0);
    let (width, height) = dataset_info.image_size();
    episode.steps = (0..3)
        .map(|i| {
            let mut step = surgvla::episode::Step::empty();
            step.rgb = vec![i as u8 * 40; width * height * 3];
            step.depth_m = vec![0.1; width * height];
            step
        })
        .collect();
    episode.meta.index = 0;
    let best: Vec<Vec<u8>> = episode
        .steps
        .iter()
        .map(|s| encode_png(width, height, 3, &s.rgb, PngLevel::Best).expect("png"))
        .collect();
    let fast = encode_png(width, height, 3, &episode.steps[0].rgb, PngLevel::Fast).expect("png");
    assert_ne!(
        best[0], fast,
        "the levels must differ for this test to mean anything"
    );
    episode.encoded = vec![EncodedFeature {
        feature: "observation.images.endoscope".into(),
        encoding: ImageEncoding::Png,
        frames: best
            .iter()
            .map(|data| EncodedFrame {
                data: data.clone(),
                keyframe: true,
            })
            .collect(),
        pixel_stats: None,
        shown: None,
        file: None,
    }];
    let root = temp_root("pass-png");
    let mut writer =
        LeRobotWriter::create(&root, &dataset_info, LeRobotOptions::default()).expect("create");
    writer
        .write_batch(std::slice::from_ref(&episode))
        .expect("write");
    writer.finish().expect("finish");
    let batch = &read_parquet(&data_files(&root).expect("files")[0]).expect("data")[0];
    let images = batch
        .column_by_name("observation.images.endoscope")
        .and_then(|c| c.as_any().downcast_ref::<arrow_array::StructArray>())
        .expect("image column");
    let bytes = images
        .column_by_name("bytes")
        .and_then(|c| c.as_any().downcast_ref::<arrow_array::BinaryArray>())
        .expect("bytes");
    for (row, expected) in best.iter().enumerate() {
        assert_eq!(bytes.value(row), expected.as_slice(), "frame {row}");
    }
}

/// A sink that only notes which stored encodings reach it.
struct Noting {
    copies_tiff: bool,
    seen: Vec<ImageEncoding>,
    next: u64,
}

impl EpisodeSink for Noting {
    fn write_batch(
        &mut self,
        episodes: &[surgvla::episode::Episode],
    ) -> Result<(), surgvla::export::ExportError> {
        for episode in episodes {
            self.seen.extend(episode.encoded.iter().map(|e| e.encoding));
            self.next += 1;
        }
        Ok(())
    }

    fn next_episode_index(&self) -> u64 {
        self.next
    }

    fn reuses_stored(&self, encoding: ImageEncoding) -> bool {
        self.copies_tiff || encoding != ImageEncoding::Tiff
    }

    fn finish_with(
        &mut self,
        _: Option<surgvla::export::Sidecar<'_>>,
    ) -> Result<surgvla::export::Summary, surgvla::export::ExportError> {
        Ok(surgvla::export::Summary::default())
    }
}

#[test]
fn a_conversion_drops_the_stored_images_its_target_would_encode_again() {
    let root = temp_root("pass-unused");
    run(&[
        "collect",
        "--out",
        path(&root),
        "--tasks",
        "T1-1",
        "--episodes-per-task",
        "2",
    ]);
    let seen = |copies_tiff: bool| {
        let mut source = surgvla::export::open_source(&root).expect("source");
        let mut sink = Noting {
            copies_tiff,
            seen: Vec::new(),
            next: 0,
        };
        surgvla::export::convert::convert(source.as_mut(), &mut sink, 2, &mut |_| {})
            .expect("convert");
        assert_eq!(sink.next, 2);
        sink.seen
    };
    // A LeRobot target copies the depth TIFFs, so they travel; RLDS stores millimetre PNGs,
    // so they are dropped as read and a batch in flight holds the depth once, as pixels.
    let all = seen(true);
    assert!(
        all.contains(&ImageEncoding::Tiff) && all.contains(&ImageEncoding::Png),
        "{all:?}"
    );
    let without = seen(false);
    assert!(!without.contains(&ImageEncoding::Tiff), "{without:?}");
    assert_eq!(
        without.len(),
        all.len() - 2,
        "one depth feature in each of 2 episodes"
    );
}
