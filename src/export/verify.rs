//! `convert --verify`: what a conversion's output holds against its input. A format surgvla
//! reads back is compared frame by frame ([`crate::export::convert::verify`]); any other is
//! validated and its episodes and frames counted against what was converted. Video the
//! conversion encoded (from pixels) is decoded and compared within a lossy tolerance.

use crate::export::convert::{ConvertError, verify, verify_within};
use crate::export::decoded::Decoded;
use crate::export::registry;
use crate::export::sink::Summary;
use crate::export::source::EpisodeSource;
use crate::export::source::SourceOptions;
use crate::export::validate::{ValidateOptions, validate};
use std::path::Path;

/// The differences between `out` and `source` (read again from its start), of which `summary`
/// says what was converted; empty when the output holds what was read.
pub fn verify_output(
    source: &mut (dyn EpisodeSource + Send),
    out: &Path,
    summary: &Summary,
) -> Result<Vec<String>, ConvertError> {
    let (format, found) = registry::detect_readable(out).map_err(ConvertError::Write)?;
    // The output states what the input did; an RLDS output of another tool's dataset has no
    // frame rate of its own, so it is read with the input's.
    let options = SourceOptions {
        fps: Some(source.info().fps),
        robot_type: Some(source.info().robot_type.clone()),
        ..Default::default()
    };
    if let Some(target) = format.open_source(&found, &options) {
        let mut target = target.map_err(ConvertError::Write)?;
        // Video the conversion encoded (the input held pixels): decoded, and compared within
        // the lossy tolerance.
        let encoded_here = Decoded::needed(target.info()) && !Decoded::needed(source.info());
        if encoded_here {
            let mut decoded = Decoded::new(target).map_err(ConvertError::Write)?;
            return Ok(verify_within(
                source,
                &mut decoded,
                Some(crate::export::convert::LOSSY_RGB_MIN_PSNR_DB),
            )?
            .differences);
        }
        return Ok(verify(source, target.as_mut())?.differences);
    }
    let report = validate(out, &ValidateOptions::default()).map_err(ConvertError::Write)?;
    let mut differences: Vec<String> = report.errors.iter().map(ToString::to_string).collect();
    if (report.episodes, report.frames) != (summary.episodes, summary.frames) {
        differences.push(format!(
            "the output holds {} episodes and {} frames, {} and {} were converted",
            report.episodes, report.frames, summary.episodes, summary.frames
        ));
    }
    Ok(differences)
}
