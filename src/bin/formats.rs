//! The output formats on the command line: `--format` / `--to` and `schema --format` (the
//! registry's formats), and each format's own flags (refused with another format).

use crate::error::CliError;
use clap::builder::PossibleValue;
use clap::{Args, ValueEnum};
use std::sync::LazyLock;
use surgvla::export::lerobot::{LeRobotOptions, LeRobotVersion, VideoOptions};
use surgvla::export::mcap::McapOptions;
use surgvla::export::pointcloud::files::CloudFileFormat;
use surgvla::export::pointcloud::{Aabb, CloudFileOptions, CloudSettings};
use surgvla::export::rlds::{RldsKeys, RldsOptions};
use surgvla::export::zarr::ZarrOptions;
use surgvla::export::{BUILTIN_FORMATS, SinkOptions};
use surgvla::media::image::PngLevel;

/// A dataset format to write (`--to`, `--format`): the registry's formats, by name, each with
/// its own help line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Format(pub surgvla::export::Format);

impl ValueEnum for Format {
    fn value_variants<'a>() -> &'a [Self] {
        static ALL: LazyLock<Vec<Format>> =
            LazyLock::new(|| BUILTIN_FORMATS.iter().copied().map(Format).collect());
        &ALL
    }

    fn to_possible_value(&self) -> Option<PossibleValue> {
        Some(PossibleValue::new(self.0.name()).help(self.0.help()))
    }
}

/// A format with a features schema (`surgvla schema --format`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct SchemaFormat(pub surgvla::export::Format);

impl ValueEnum for SchemaFormat {
    fn value_variants<'a>() -> &'a [Self] {
        static ALL: LazyLock<Vec<SchemaFormat>> = LazyLock::new(|| {
            BUILTIN_FORMATS
                .iter()
                .filter(|f| f.schema_help().is_some())
                .copied()
                .map(SchemaFormat)
                .collect()
        });
        &ALL
    }

    fn to_possible_value(&self) -> Option<PossibleValue> {
        let value = PossibleValue::new(self.0.name());
        Some(match self.0.schema_help() {
            Some(help) => value.help(help),
            None => value,
        })
    }
}

/// The codec of video mode.
#[derive(ValueEnum, Clone, Copy, Debug)]
pub(crate) enum VideoCodec {
    /// AV1 (rav1e), LeRobot's codec family.
    Av1,
    /// H.264 (openh264), faster.
    H264,
}

/// The LeRobot layout.
#[derive(ValueEnum, Clone, Copy, Debug)]
pub(crate) enum LayoutVersion {
    /// v3.0 (current): many episodes per file, parquet metadata.
    #[value(name = "3.0")]
    V30,
    /// v2.1: one file per episode, JSON-lines metadata.
    #[value(name = "2.1")]
    V21,
}

/// Options of the LeRobot format.
#[derive(Args, Debug)]
#[command(next_help_heading = "LeRobot")]
pub(crate) struct LeRobotArgs {
    /// LeRobot: store the endoscope RGB as MP4 video (video mode) instead of PNG: av1 (rav1e,
    /// LeRobot's codec family) or h264 (openh264, faster). `--video` alone means av1.
    #[arg(long, value_enum, num_args = 0..=1, default_missing_value = "av1")]
    video: Option<VideoCodec>,
    /// LeRobot layout: 3.0 (current, the default) or 2.1 (one file per episode, JSON-lines
    /// metadata).
    #[arg(long, value_enum)]
    lerobot_version: Option<LayoutVersion>,
    /// LeRobot: size at which a data file is closed and a new one begun, MB (LeRobot's
    /// data_files_size_in_mb; default 100); each closed file is also a resume checkpoint. Video
    /// files close with it, or when one holds 200 MB of samples (video_files_size_in_mb).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=100_000))]
    data_file_mb: Option<u64>,
}

impl LeRobotArgs {
    /// The first LeRobot option given, by flag.
    fn given(&self) -> Option<&'static str> {
        [
            self.video.map(|_| "--video"),
            self.lerobot_version.map(|_| "--lerobot-version"),
            self.data_file_mb.map(|_| "--data-file-mb"),
        ]
        .into_iter()
        .flatten()
        .next()
    }

    fn options(&self) -> LeRobotOptions {
        let defaults = LeRobotOptions::default();
        LeRobotOptions {
            video: self.video.map(|codec| match codec {
                VideoCodec::H264 => VideoOptions::h264(),
                VideoCodec::Av1 => VideoOptions::default(),
            }),
            version: match self.lerobot_version {
                Some(LayoutVersion::V21) => LeRobotVersion::V21,
                Some(LayoutVersion::V30) | None => LeRobotVersion::V30,
            },
            data_file_size_mb: self.data_file_mb.unwrap_or(defaults.data_file_size_mb),
            ..defaults
        }
    }
}

/// Options of the RLDS format.
#[derive(Args, Debug)]
#[command(next_help_heading = "RLDS")]
pub(crate) struct RldsArgs {
    /// RLDS: the dataset name, its folder and shard prefix, what `tfds.builder(name)` takes
    /// (snake_case; default surgvla_benchmark).
    #[arg(long)]
    rlds_name: Option<String>,
    /// RLDS: the version folder, x.y.z (default 1.0.0).
    #[arg(long)]
    rlds_version: Option<String>,
    /// RLDS: a shard is closed once it reaches this size, MB (default 64, TFDS's smallest
    /// shard size); each closed shard is also a resume checkpoint.
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=4096))]
    rlds_shard_mb: Option<u64>,
    /// RLDS: the observation key of the endoscope RGB image (default image, OpenVLA's).
    #[arg(long)]
    rlds_image_key: Option<String>,
    /// RLDS: the observation key of the 7-D robot state (default state).
    #[arg(long)]
    rlds_state_key: Option<String>,
    /// RLDS: the observation key of the depth image (default depth).
    #[arg(long)]
    rlds_depth_key: Option<String>,
    /// RLDS: how the RGB image is stored: png (lossless, the default) or jpeg (what Open
    /// X-Embodiment and OpenVLA's datasets use, a fraction of the size; lossy).
    #[arg(long, value_enum)]
    rlds_image_encoding: Option<RldsImageEncoding>,
    /// RLDS: the JPEG quality, 1-100 (default 95, TensorFlow's encode_jpeg default); giving
    /// it alone implies --rlds-image-encoding jpeg.
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=100))]
    rlds_jpeg_quality: Option<u8>,
}

/// How RLDS stores the RGB image.
#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum RldsImageEncoding {
    /// PNG, lossless.
    Png,
    /// Baseline JPEG (4:2:0), lossy.
    Jpeg,
}

impl RldsArgs {
    /// The first RLDS option given, by flag.
    fn given(&self) -> Option<&'static str> {
        [
            self.rlds_name.as_ref().map(|_| "--rlds-name"),
            self.rlds_version.as_ref().map(|_| "--rlds-version"),
            self.rlds_shard_mb.map(|_| "--rlds-shard-mb"),
            self.rlds_image_key.as_ref().map(|_| "--rlds-image-key"),
            self.rlds_state_key.as_ref().map(|_| "--rlds-state-key"),
            self.rlds_depth_key.as_ref().map(|_| "--rlds-depth-key"),
            self.rlds_image_encoding.map(|_| "--rlds-image-encoding"),
            self.rlds_jpeg_quality.map(|_| "--rlds-jpeg-quality"),
        ]
        .into_iter()
        .flatten()
        .next()
    }

    fn options(&self) -> RldsOptions {
        let defaults = RldsOptions::default();
        let keys = RldsKeys::default();
        let or = |given: &Option<String>, default: String| given.clone().unwrap_or(default);
        RldsOptions {
            name: or(&self.rlds_name, defaults.name),
            version: or(&self.rlds_version, defaults.version),
            shard_size_mb: self.rlds_shard_mb.unwrap_or(defaults.shard_size_mb),
            png: PngLevel::Fast,
            keys: RldsKeys {
                image: or(&self.rlds_image_key, keys.image),
                state: or(&self.rlds_state_key, keys.state),
                depth: or(&self.rlds_depth_key, keys.depth),
                ..keys
            },
            jpeg_quality: match (self.rlds_image_encoding, self.rlds_jpeg_quality) {
                (Some(RldsImageEncoding::Png), _) => None,
                (Some(RldsImageEncoding::Jpeg), quality) => Some(quality.unwrap_or(95)),
                (None, quality) => quality,
            },
        }
    }
}

/// Options of the point-cloud formats.
#[derive(Args, Debug)]
#[command(next_help_heading = "Point clouds and zarr")]
pub(crate) struct CloudArgs {
    /// Point clouds: points per frame (default 1024; DP3 also uses 512).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=65_536))]
    points: Option<u64>,
    /// Point clouds: the crop box in the world frame, metres: MINX,MINY,MINZ,MAXX,MAXY,MAXZ
    /// (default: the robot's workspace with 20 mm margins, from the dataset).
    #[arg(long, value_parser = parse_box)]
    crop: Option<Aabb>,
    /// zarr: also store the images (data/img RGB, data/depth metres).
    #[arg(long)]
    zarr_images: bool,
    /// zarr: a seventh point channel with the point's mask id (needs a dataset with the mask).
    #[arg(long)]
    zarr_mask_channel: bool,
}

fn parse_box(text: &str) -> Result<Aabb, String> {
    let values: Vec<f64> = text
        .split(',')
        .map(|v| v.trim().parse::<f64>().map_err(|e| format!("{v:?}: {e}")))
        .collect::<Result<_, _>>()?;
    let [x0, y0, z0, x1, y1, z1]: [f64; 6] = values
        .try_into()
        .map_err(|_| "six numbers: MINX,MINY,MINZ,MAXX,MAXY,MAXZ".to_string())?;
    if ![x0, y0, z0, x1, y1, z1].iter().all(|v| v.is_finite()) || x0 >= x1 || y0 >= y1 || z0 >= z1 {
        return Err("finite numbers with each minimum below its maximum".into());
    }
    Ok(Aabb {
        min_m: [x0, y0, z0],
        max_m: [x1, y1, z1],
    })
}

impl CloudArgs {
    fn given(&self) -> Option<&'static str> {
        [self.points.map(|_| "--points"), self.crop.map(|_| "--crop")]
            .into_iter()
            .flatten()
            .next()
    }

    fn zarr_given(&self) -> Option<&'static str> {
        [
            self.zarr_images.then_some("--zarr-images"),
            self.zarr_mask_channel.then_some("--zarr-mask-channel"),
        ]
        .into_iter()
        .flatten()
        .next()
    }

    fn settings(&self) -> CloudSettings {
        let defaults = CloudSettings::default();
        CloudSettings {
            points: self.points.map_or(defaults.points, |p| p as usize),
            crop: self.crop,
            ..defaults
        }
    }

    /// The options of every format that makes point clouds.
    fn options(&self) -> Vec<Box<dyn SinkOptions>> {
        let settings = self.settings();
        let mut options: Vec<Box<dyn SinkOptions>> = CloudFileFormat::ALL
            .into_iter()
            .map(|format| Box::new(CloudFileOptions { format, settings }) as Box<dyn SinkOptions>)
            .collect();
        options.push(Box::new(self.zarr()));
        options.push(Box::new(McapOptions { cloud: settings }));
        options
    }

    fn zarr(&self) -> ZarrOptions {
        ZarrOptions {
            cloud: self.settings(),
            images: self.zarr_images,
            mask_channel: self.zarr_mask_channel,
        }
    }
}

/// Flags that belong to some formats: who owns them (for the message refusing them), the first
/// one given, and the options they make, one per format they apply to.
struct FlagGroup {
    owner: &'static str,
    given: Option<&'static str>,
    options: Vec<Box<dyn SinkOptions>>,
}

/// Every format's options, for a command that writes one format.
#[derive(Args, Debug)]
pub(crate) struct FormatArgs {
    #[command(flatten)]
    lerobot: LeRobotArgs,
    #[command(flatten)]
    rlds: RldsArgs,
    #[command(flatten)]
    cloud: CloudArgs,
}

impl FormatArgs {
    /// The options of `format`; another format's option is a usage error (`flag` names how
    /// the format was chosen, e.g. "--format").
    pub(crate) fn sink_options(
        &self,
        format: Format,
        flag: &str,
    ) -> Result<Box<dyn SinkOptions>, CliError> {
        let groups = [
            FlagGroup {
                owner: "a LeRobot",
                given: self.lerobot.given(),
                options: vec![Box::new(self.lerobot.options())],
            },
            FlagGroup {
                owner: "an RLDS",
                given: self.rlds.given(),
                options: vec![Box::new(self.rlds.options())],
            },
            FlagGroup {
                owner: "a point-cloud",
                given: self.cloud.given(),
                options: self.cloud.options(),
            },
            FlagGroup {
                owner: "a zarr",
                given: self.cloud.zarr_given(),
                options: vec![Box::new(self.cloud.zarr())],
            },
        ];
        // Only the chosen format's options may be given.
        for group in &groups {
            if let Some(option) = group.given
                && !group.options.iter().any(|o| o.format() == format.0)
            {
                return Err(CliError::usage(format!(
                    "{option} is {} option; it means nothing with {flag} {}",
                    group.owner,
                    format.0.name()
                )));
            }
        }
        let options = groups
            .into_iter()
            .flat_map(|group| group.options)
            .find(|o| o.format() == format.0)
            .ok_or_else(|| CliError::usage(format!("{flag} {} has no options", format.0.name())))?;
        options.check()?;
        Ok(options)
    }

    /// The LeRobot options Open-H asks for (`--profile open-h`): layout 2.1 in video mode
    /// (H.264 unless `--video` names another codec); layout 3.0 or another format's option is
    /// a usage error.
    pub(crate) fn open_h_options(&self, format: Format) -> Result<Box<dyn SinkOptions>, CliError> {
        if format.0.name() != "lerobot" {
            return Err(CliError::usage(format!(
                "--profile open-h writes LeRobot (Open-H's format), not {}",
                format.0.name()
            )));
        }
        self.sink_options(format, "--to")?;
        if matches!(self.lerobot.lerobot_version, Some(LayoutVersion::V30)) {
            return Err(CliError::usage(
                "--profile open-h writes LeRobot 2.1 (Open-H's validator loads it with lerobot 0.3.3), not --lerobot-version 3.0",
            ));
        }
        let mut options = self.lerobot.options();
        options.version = LeRobotVersion::V21;
        options.video.get_or_insert_with(VideoOptions::h264);
        options.check()?;
        Ok(Box::new(options))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Flags {
        #[arg(long, value_enum)]
        to: Format,
        #[command(flatten)]
        formats: FormatArgs,
    }

    #[test]
    fn every_registered_format_is_a_value_whose_flags_make_its_options() {
        let values: Vec<String> = Format::value_variants()
            .iter()
            .filter_map(|f| f.to_possible_value())
            .map(|v| v.get_name().to_string())
            .collect();
        assert_eq!(values.len(), BUILTIN_FORMATS.len(), "{values:?}");
        for format in BUILTIN_FORMATS {
            let flags = Flags::try_parse_from(["surgvla", "--to", format.name()])
                .unwrap_or_else(|e| panic!("--to {}: {e}", format.name()));
            let options = flags
                .formats
                .sink_options(flags.to, "--to")
                .unwrap_or_else(|e| panic!("{}: {}", format.name(), e.message()));
            assert_eq!(options.format(), *format);
        }
        // Another format's flag is refused, naming its owner.
        let flags =
            Flags::try_parse_from(["surgvla", "--to", "rlds", "--points", "512"]).expect("parses");
        let refused = flags
            .formats
            .sink_options(flags.to, "--to")
            .expect_err("refused");
        assert!(
            refused
                .message()
                .contains("--points is a point-cloud option"),
            "{}",
            refused.message()
        );
    }
}
