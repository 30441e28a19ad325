//! What a task episode is set up from and as: spawn ranges, the options of scene construction
//! ([`TaskConfig`]) and the drawn [`TaskInstance`]. Plain data that spawning
//! ([`super::spawn`]) and placement ([`super::placement`]) both use.

use crate::scene::SceneSpec;
use crate::task::id::TaskId;

/// Most distractors at level 2.
pub const MAX_DISTRACTORS: usize = 3;

/// Which instruction an episode gets.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum InstructionChoice {
    /// Always the canonical instruction.
    #[default]
    Canonical,
    /// A seeded choice among the paraphrases.
    Paraphrase,
    /// A seeded choice among the canonical instruction and the paraphrases.
    Mixed,
    /// The detailed prompt: the target described and the distractors named ("pick up the
    /// gauze, not the needle").
    Detailed,
    /// An instruction naming an object the scene does not hold (LIBERO-PRO's probe): success
    /// then means the policy did the scene's task regardless of what it was told.
    AbsentObject,
}

impl InstructionChoice {
    /// The option's name ("canonical", "paraphrase", "mixed", "detailed", "absent_object").
    pub fn name(self) -> &'static str {
        match self {
            InstructionChoice::Canonical => "canonical",
            InstructionChoice::Paraphrase => "paraphrase",
            InstructionChoice::Mixed => "mixed",
            InstructionChoice::Detailed => "detailed",
            InstructionChoice::AbsentObject => "absent_object",
        }
    }
}

/// A closed interval `(low, high)`.
pub type Range = (f64, f64);

/// Where a task's things spawn, world frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SpawnRanges {
    /// The primary thing: the object to pick, or the organ's centre (T1-3, T2-3, T3-2), metres.
    pub primary_x_m: Range,
    pub primary_y_m: Range,
    /// The second thing: the first distractor (T2-1, T2-2), the block (T3-1), the gauze (T3-2).
    pub secondary_x_m: Range,
    pub secondary_y_m: Range,
    /// Yaw of the primary object or organ, degrees.
    pub yaw_deg: Range,
}

impl SpawnRanges {
    /// Every range's half width multiplied by `scale` about its centre (1 = unchanged).
    pub fn scaled(&self, scale: f64) -> SpawnRanges {
        let s = |(low, high): Range| {
            let (mid, half) = ((low + high) / 2.0, (high - low) / 2.0 * scale);
            (mid - half, mid + half)
        };
        SpawnRanges {
            primary_x_m: s(self.primary_x_m),
            primary_y_m: s(self.primary_y_m),
            secondary_x_m: s(self.secondary_x_m),
            secondary_y_m: s(self.secondary_y_m),
            yaw_deg: s(self.yaw_deg),
        }
    }
}

/// Options of scene construction shared by all tasks.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TaskConfig {
    /// Distractors in T2-1 and T2-2 (1 to [`MAX_DISTRACTORS`]).
    pub distractors: usize,
    pub instruction: InstructionChoice,
    /// Multiplies the half width of every spawn range (1 = the reference ranges; 3 gives the
    /// needle's evaluation range of +-0.03 m).
    pub spawn_scale: f64,
    /// T2-3: the target site's colour varies per episode and the instruction names it; when
    /// false the red site is always the target (the reference's single instruction).
    pub vary_clip_target: bool,
}

impl Default for TaskConfig {
    fn default() -> Self {
        TaskConfig {
            distractors: 1,
            instruction: InstructionChoice::Canonical,
            spawn_scale: 1.0,
            vary_clip_target: true,
        }
    }
}

/// One episode's setup.
#[derive(Clone, Debug, PartialEq)]
pub struct TaskInstance {
    pub task: TaskId,
    pub seed: u64,
    pub scene: SceneSpec,
    pub instruction: String,
    /// The object the instruction names (pick and place tasks), index into `scene.objects`.
    pub target_object: Option<usize>,
    /// The object to place it on (T3-1's block).
    pub support_object: Option<usize>,
    /// The mark the instruction names (T1-3, T2-3, T3-2), index into `scene.marks`.
    pub target_mark: Option<usize>,
}
