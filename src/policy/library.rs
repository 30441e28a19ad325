//! The set of expert plans a collection uses: the built-in `scripted_policies/*.toml` (compiled
//! into the binary, so it runs from any folder) and, optionally, a folder of plans that replace
//! them task by task.

use crate::policy::plan::{ExpertPlan, PlanError};
use crate::task::TaskId;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The built-in plans: (file name, text).
const BUILTIN: [(&str, &str); 8] = [
    (
        "gauze_pick.toml",
        include_str!("../../scripted_policies/gauze_pick.toml"),
    ),
    (
        "needle_pick.toml",
        include_str!("../../scripted_policies/needle_pick.toml"),
    ),
    (
        "electrocoagulation.toml",
        include_str!("../../scripted_policies/electrocoagulation.toml"),
    ),
    (
        "gauze_pick_distractors.toml",
        include_str!("../../scripted_policies/gauze_pick_distractors.toml"),
    ),
    (
        "needle_pick_distractors.toml",
        include_str!("../../scripted_policies/needle_pick_distractors.toml"),
    ),
    (
        "vessel_clipping.toml",
        include_str!("../../scripted_policies/vessel_clipping.toml"),
    ),
    (
        "pick_and_place.toml",
        include_str!("../../scripted_policies/pick_and_place.toml"),
    ),
    (
        "hemostasis.toml",
        include_str!("../../scripted_policies/hemostasis.toml"),
    ),
];

/// Expert plans by task.
#[derive(Clone, Debug, PartialEq)]
pub struct ExpertLibrary {
    plans: BTreeMap<TaskId, ExpertPlan>,
    /// The plans that replace built-in ones: task -> CRC-32C of the plan file's text.
    custom: BTreeMap<TaskId, u32>,
}

impl ExpertLibrary {
    /// The plans in `scripted_policies/`, as compiled in.
    pub fn builtin() -> Result<Self, PlanError> {
        let mut plans = BTreeMap::new();
        for (name, text) in BUILTIN {
            let path = Path::new("scripted_policies").join(name);
            let plan = ExpertPlan::parse(text, &path)?;
            let task = plan.task_id().map_err(|e| PlanError::Invalid {
                path: path.clone(),
                message: e.to_string(),
            })?;
            plans.insert(task, plan);
        }
        Ok(ExpertLibrary {
            plans,
            custom: BTreeMap::new(),
        })
    }

    /// The built-in plans, with every `*.toml` in `folder` replacing the plan of its task.
    pub fn with_folder(folder: &Path) -> Result<Self, PlanError> {
        let mut library = Self::builtin()?;
        let io = |source| PlanError::Io {
            path: folder.to_path_buf(),
            source,
        };
        let mut paths: Vec<_> = std::fs::read_dir(folder)
            .map_err(io)?
            .map(|entry| entry.map(|e| e.path()))
            .collect::<Result<_, _>>()
            .map_err(io)?;
        paths.retain(|p| p.extension().is_some_and(|e| e == "toml"));
        paths.sort();
        if paths.is_empty() {
            return Err(PlanError::Invalid {
                path: folder.to_path_buf(),
                message: "no *.toml plan in this folder".into(),
            });
        }
        let mut sources: BTreeMap<TaskId, PathBuf> = BTreeMap::new();
        for path in paths {
            let text =
                crate::files::read_regular_to_string(&path).map_err(|source| PlanError::Io {
                    path: path.clone(),
                    source,
                })?;
            let plan = ExpertPlan::parse(&text, &path)?;
            let task = plan.task_id().map_err(|e| PlanError::Invalid {
                path: path.clone(),
                message: e.to_string(),
            })?;
            if let Some(first) = sources.get(&task) {
                return Err(PlanError::Invalid {
                    path: path.clone(),
                    message: format!(
                        "a second plan for {} ({}); {} has one too: keep one plan per task",
                        task.name(),
                        task.code(),
                        first.display()
                    ),
                });
            }
            let instance = task
                .instance(0, &crate::task::TaskConfig::default())
                .map_err(|e| PlanError::Invalid {
                    path: path.clone(),
                    message: format!("its task cannot be set up: {}", e.problem),
                })?;
            plan.check_frames(&instance)
                .map_err(|e| PlanError::Invalid {
                    path: path.clone(),
                    message: e.to_string(),
                })?;
            sources.insert(task, path);
            library.plans.insert(task, plan);
            library.custom.insert(task, crc32c::crc32c(text.as_bytes()));
        }
        Ok(library)
    }

    /// Whether any plan replaces a built-in one.
    pub fn is_custom(&self) -> bool {
        !self.custom.is_empty()
    }

    /// The plans that replace built-in ones, by task name, with the CRC-32C of their text:
    /// what a dataset records so that a resume with edited plans is refused.
    pub fn custom_plans(&self) -> BTreeMap<&'static str, String> {
        self.custom
            .iter()
            .map(|(task, crc)| (task.name(), format!("{crc:08x}")))
            .collect()
    }

    /// The plan of `task`.
    pub fn plan(&self, task: TaskId) -> Result<&ExpertPlan, PlanError> {
        self.plans.get(&task).ok_or(PlanError::Missing(task))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_task_has_a_builtin_plan_named_after_it() {
        let library = ExpertLibrary::builtin().unwrap();
        for (task, (file, _)) in TaskId::ALL.into_iter().zip(BUILTIN) {
            assert_eq!(library.plan(task).unwrap().task_id(), Ok(task));
            assert_eq!(file, format!("{}.toml", task.name()));
        }
    }

    #[test]
    fn a_folder_replaces_plans_and_bad_files_are_named() {
        let folder = std::env::temp_dir().join(format!("surgvla-plans-{}", std::process::id()));
        std::fs::create_dir_all(&folder).unwrap();
        let text = BUILTIN[0]
            .1
            .replace("speed_factor = [", "speed_factor = [0.3, 0.3] # [");
        std::fs::write(folder.join("mine.toml"), &text).unwrap();
        let library = ExpertLibrary::with_folder(&folder).unwrap();
        assert_eq!(
            library.plan(TaskId::GauzePick).unwrap().speed_factor,
            [0.3, 0.3]
        );
        std::fs::write(folder.join("zz_bad.toml"), "task = 'gauze_pick'\nspeed = 1").unwrap();
        let error = ExpertLibrary::with_folder(&folder).unwrap_err().to_string();
        assert!(error.contains("zz_bad.toml"), "{error}");
        std::fs::remove_dir_all(&folder).unwrap();
    }
}
