//! `surgvla tasks`: the tasks with their ids, levels, step limits and instructions.

use crate::error::CliError;
use surgvla::task::TaskId;

pub(crate) fn run_tasks() -> Result<(), CliError> {
    for task in TaskId::ALL {
        say!(
            "{}  L{}  {:<24} {:>3} steps  \"{}\"",
            task.code(),
            task.level(),
            task.name(),
            task.step_limit(),
            task.instruction()
        );
        for paraphrase in task.paraphrases() {
            say!("{:>41}  or \"{paraphrase}\"", "");
        }
    }
    Ok(())
}
