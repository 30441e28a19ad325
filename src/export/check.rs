//! The names of `validate`'s checks: one [`Check`] per kind of finding, each with the name a
//! report prints and its JSON holds (`"check": "video-decode"`) and a line saying what it
//! verifies. docs/validate.md's table of checks is kept equal to [`Check::ALL`] by a test.

use serde::Serialize;

macro_rules! checks {
    ($($variant:ident = $name:literal: $what:literal,)*) => {
        /// One of `validate`'s checks: what a [`crate::export::findings::Finding`] was found
        /// by. Ordered by name, the order of a report.
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
        pub enum Check {
            $(#[doc = $what] $variant,)*
        }

        impl Check {
            /// Every check, in declaration (alphabetical) order.
            pub const ALL: &'static [Check] = &[$(Check::$variant,)*];

            /// The name reports print and their JSON holds.
            pub fn name(self) -> &'static str {
                match self {
                    $(Check::$variant => $name,)*
                }
            }

            /// What the check verifies, one line.
            pub fn what(self) -> &'static str {
                match self {
                    $(Check::$variant => $what,)*
                }
            }
        }
    };
}

checks! {
    ActionJump = "action-jump": "lint: no action step jumps far beyond the dataset's usual step",
    ActionLag = "action-lag": "lint: each action best predicts the state's next step, not one k frames away",
    BlankCamera = "blank-camera": "lint: no decoded camera frame is blank (black or one colour)",
    CameraSwap = "camera-swap": "lint: no two cameras of one shape trade pictures within an episode",
    Card = "card": "README.md's dataset card is present and lists the dataset's tasks",
    Checksum = "checksum": "every file our manifest lists has its recorded size and CRC-32C",
    Chunk = "chunk": "zarr chunks are present, zstd frames and of the size their array declares",
    ChunkLength = "chunk-length": "lint: how many episodes are shorter than ACT's, pi0's and diffusion's action chunks",
    Clipping = "clipping": "lint: no action dimension sits at its minimum or maximum for half its values",
    Cloud = "cloud": "a PLY or PCD frame's header parses and its body holds exactly the points it declares, all finite",
    Columns = "columns": "a LeRobot table has a column for each declared feature and no other",
    Constant = "constant": "lint: every numeric dimension varies across the dataset",
    Crc = "crc": "TFRecord and MCAP framing: lengths and CRCs are intact to the end of the file",
    Drift = "drift": "lint: a task's last episodes do not drift from its first",
    DuplicateEpisodes = "duplicate-episodes": "lint: no two episodes are copies",
    EpisodeLength = "episode-length": "lint: no episode is under a second, a single frame or an outlier in length",
    EpisodeEnds = "episode_ends": "DP3's episode_ends rise and end at the frame count",
    EpisodeIndex = "episode_index": "episode indices in the data and metadata agree and rise",
    Episodes = "episodes": "the episode metadata lists each episode once, in order",
    EpochTimestamps = "epoch-timestamps": "lint: timestamps count from the episode's start, not the epoch",
    Features = "features": "an RLDS record holds exactly the features features.json declares",
    Finite = "finite": "numeric values are finite (no NaN or Inf)",
    Flags = "flags": "RLDS is_first/is_last/is_terminal are 0/1 and mark the episode's ends",
    FrameIndex = "frame_index": "frame indices start at 0 and rise by one within an episode",
    Frames = "frames": "a point-cloud dataset holds one file per frame its metadata states",
    FromTo = "from_to": "an episode's dataset_from_index/dataset_to_index bound its rows",
    FrozenAction = "frozen-action": "lint: no episode repeats its actions unchanged for 5 % of its frames",
    FrozenCamera = "frozen-camera": "lint: no camera shows one picture while the robot moves",
    Gripper = "gripper": "gripper actions take the values the dataset's gripper encoding allows",
    GripperRange = "gripper-range": "lint: gripper values lie in the range their encoding states",
    Image = "image": "stored images decode to the declared size and channels",
    Index = "index": "the global index starts where the previous episode ended and rises",
    Instruction = "instruction": "every task's language instruction is non-empty",
    Interrupted = "interrupted": "the dataset was finished: no writer left it interrupted (its marker)",
    Json = "json": "an MCAP JSON message parses",
    JsonSchema = "json_schema": "an MCAP JSON message matches its Foxglove schema",
    Length = "length": "an episode's recorded length is its number of rows",
    Location = "location": "an episode's chunk and file indices name the file holding it",
    Magic = "magic": "the file begins (and ends) with its format's magic bytes",
    Manifest = "manifest": "our manifest parses and lists only paths inside the dataset",
    Open = "open": "the dataset's folder can be opened as its format",
    Outliers = "outliers": "lint: no value lies 10 standard deviations from its dimension's mean",
    Paths = "paths": "names and path templates from the metadata stay inside the dataset",
    PoseJump = "pose-jump": "lint: the tool tip moves no faster than a surgical robot can",
    Present = "present": "every file the format requires exists",
    Profile = "profile": "`--profile open-h`: Open-H-Embodiment's contribution guide (format, features, splits, README, rates)",
    Provenance = "provenance": "our episodes record their task id, seed and attempts",
    Quaternion = "quaternion": "lint: quaternions have unit norm",
    QuaternionSign = "quaternion-sign": "lint: consecutive quaternions stay in one hemisphere",
    Readable = "readable": "a file can be read and parsed",
    Record = "record": "a TFRecord record is a tf.train.Example",
    Replay = "replay": "`--replay`: the recorded actions, replayed, give the recorded episode",
    SameInstruction = "same-instruction": "lint: different tasks have different instructions",
    Schema = "schema": "a format's declared schema (zarr arrays, features) is one we read",
    SchemaName = "schema_name": "MCAP schemas are Foxglove's well-known ones",
    Shape = "shape": "arrays have the shapes their feature declares",
    ShardLengths = "shard_lengths": "each TFRecord shard holds the episodes shardLengths gives",
    Shards = "shards": "the shards on disk are the ones dataset_info.json lists",
    SplitOverlap = "split-overlap": "lint: no two splits share an initial state",
    Stats = "stats": "per-episode and global statistics are present and complete",
    StepCounts = "step_counts": "every per-step RLDS feature holds one value per step",
    StepLimit = "step_limit": "no episode is longer than its task's step limit",
    Steps = "steps": "no episode is empty",
    StuckDimension = "stuck-dimension": "lint: no action or state dimension is stuck in most episodes",
    Summary = "summary": "MCAP's summary section (indexes, statistics) matches the file",
    TaskBalance = "task-balance": "lint: no task has ten times the episodes of another",
    TaskIndex = "task_index": "every task_index names a row of the tasks table",
    Tasks = "tasks": "the tasks table is complete, in order and names each episode's task",
    Timestamps = "timestamps": "timestamps rise at the dataset's fps",
    Totals = "totals": "info.json's totals are what the data holds",
    Training = "training": "lint: an action feature lerobot-train can read",
    Types = "types": "columns have the types their features declare",
    Units = "units": "lint: positions are in the unit their names declare",
    Video = "video": "a video holds the declared codec, size and frame count",
    VideoDecode = "video-decode": "every frame of a video decodes to the declared size",
    VideoStats = "video-stats": "decoded frames agree with the episode's stored image statistics",
    Videos = "videos": "a video feature has its videos/<key>/... columns",
    Workspace = "workspace": "the tool tip stays inside the task's workspace",
}

impl std::fmt::Display for Check {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl PartialOrd for Check {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for Check {
    /// By name, so that a report's order is the order of the names it prints.
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.name().cmp(other.name())
    }
}

impl Serialize for Check {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_str(self.name())
    }
}

impl PartialEq<&str> for Check {
    fn eq(&self, other: &&str) -> bool {
        self.name() == *other
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_unique_and_declared_in_their_order() {
        let names: Vec<&str> = Check::ALL.iter().map(|c| c.name()).collect();
        let mut sorted = names.clone();
        sorted.sort_unstable();
        sorted.dedup();
        assert_eq!(names, sorted, "declare checks once each, by name");
        assert!(Check::ALL.windows(2).all(|w| w[0] < w[1]));
    }

    #[test]
    fn serialises_as_its_name() {
        let json = serde_json::to_string(&Check::VideoDecode).expect("json");
        assert_eq!(json, "\"video-decode\"");
        assert_eq!(Check::ShardLengths.to_string(), "shard_lengths");
    }
}
