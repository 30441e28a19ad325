//! `surgvla contact-sheet`: the start frame of all eight tasks in one PNG grid.

use crate::commands::render::LookArgs;
use crate::error::CliError;
use std::path::PathBuf;
use surgvla::render::image::write_png_file;
use surgvla::task::TaskId;
use surgvla::view::contact_sheet;

#[derive(clap::Args, Debug)]
pub(crate) struct ContactSheetArgs {
    /// Output PNG.
    #[arg(long, default_value = "contact_sheet.png", value_parser = crate::app::png_path)]
    out: PathBuf,
    /// Seed of every scene.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    #[command(flatten)]
    look: LookArgs,
}

pub(crate) fn run_contact_sheet(args: &ContactSheetArgs) -> Result<(), CliError> {
    let (options, appearance) = args.look.options(args.seed);
    let sheet = contact_sheet(&TaskId::ALL, args.seed, options, appearance)?;
    write_png_file(&args.out, sheet.width_px, sheet.height_px, 3, &sheet.rgb)?;
    say!(
        "wrote {} ({}x{}): columns {}; rows RGB, depth, mask",
        args.out.display(),
        sheet.width_px,
        sheet.height_px,
        TaskId::ALL.map(|t| t.code()).join(", ")
    );
    Ok(())
}
