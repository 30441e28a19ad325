//! `surgvla schema`: a format's features schema, for the formats that have one.

use crate::error::CliError;
use crate::formats::SchemaFormat;
use surgvla::policy::ExpertLibrary;

#[derive(clap::Args, Debug)]
pub(crate) struct SchemaArgs {
    /// Include the segmentation mask feature.
    #[arg(long)]
    pub with_mask: bool,
    /// The format: lerobot (info.json's features), rlds (features.json) or mcap (the JSON
    /// channels' schemas).
    #[arg(long, value_enum, default_value = "lerobot")]
    pub format: SchemaFormat,
}

pub(crate) fn run_schema(args: &SchemaArgs) -> Result<(), CliError> {
    let (with_mask, format) = (args.with_mask, args.format);
    let set = surgvla::episode::FeatureSet {
        mask: with_mask,
        ..Default::default()
    };
    let options = surgvla::collect::run::CollectOptions::default();
    let info = surgvla::collect::run::dataset_info(&options, set, &ExpertLibrary::builtin()?);
    let json = format
        .0
        .schema(&info)
        .ok_or_else(|| CliError::usage(format!("{} has no features schema", format.0.name())))?;
    say!("{}", serde_json::to_string_pretty(&json)?);
    Ok(())
}
