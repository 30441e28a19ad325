//! What `edit` keeps and where it goes: [`Selector`]s (`--keep` / `--drop`: index lists,
//! a task, a length, a provenance field, validate's findings), [`Splits`] (`--split`: seeded
//! fractions stratified by task, or index lists) and [`choose`], which turns a dataset's
//! [`Skimmed`] episodes into the outputs to write, each an ordered list of input episodes.

use crate::export::source::Skimmed;
use std::collections::BTreeMap;
use std::ops::Range;

/// Which episodes a `--keep` or `--drop` names.
#[derive(Clone, Debug, PartialEq)]
pub enum Selector {
    /// Input episode indices: `1,3,6-8` (ranges inclusive).
    Indices(Vec<Range<u64>>),
    /// `task=X`: the task id (`T1-1`, any case) or the instruction (case and surrounding
    /// spaces aside).
    Task(String),
    /// `length<N` (also `<=`, `>`, `>=`, `=`): the episode's steps against N.
    Length(Comparison, u64),
    /// `KEY=VALUE`: a provenance field (`success`, `seed`, `level`, `attempts`,
    /// `instruction`) or a per-episode value another tool's dataset carries, by its key.
    Field(String, String),
    /// `flagged` (any finding of `validate --lint` names the episode) or `flagged=errors`
    /// (an error does).
    Flagged { errors_only: bool },
}

/// How [`Selector::Length`] compares.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Comparison {
    Less,
    LessOrEqual,
    Greater,
    GreaterOrEqual,
    Equal,
}

impl Comparison {
    fn holds(self, a: u64, b: u64) -> bool {
        match self {
            Comparison::Less => a < b,
            Comparison::LessOrEqual => a <= b,
            Comparison::Greater => a > b,
            Comparison::GreaterOrEqual => a >= b,
            Comparison::Equal => a == b,
        }
    }
}

/// Provenance fields every surgvla episode records.
const PROVENANCE: &[&str] = &["success", "seed", "level", "attempts", "instruction"];

/// `1,3,6-8`: indices and inclusive ranges.
pub fn parse_indices(text: &str) -> Result<Vec<Range<u64>>, String> {
    let number = |t: &str| {
        t.trim()
            .parse::<u64>()
            .map_err(|_| format!("{t:?} is not an episode index"))
    };
    text.split(',')
        .map(|part| match part.split_once('-') {
            Some((from, to)) => {
                let (from, to) = (number(from)?, number(to)?);
                if to < from {
                    return Err(format!("{part:?}: the range ends before it starts"));
                }
                Ok(from..to.saturating_add(1))
            }
            None => number(part).map(|i| i..i.saturating_add(1)),
        })
        .collect()
}

impl std::str::FromStr for Selector {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        let text = text.trim();
        if let Some(rest) = text.strip_prefix("length") {
            let (comparison, number) = [
                ("<=", Comparison::LessOrEqual),
                (">=", Comparison::GreaterOrEqual),
                ("==", Comparison::Equal),
                ("<", Comparison::Less),
                (">", Comparison::Greater),
                ("=", Comparison::Equal),
            ]
            .into_iter()
            .find_map(|(op, c)| rest.trim().strip_prefix(op).map(|n| (c, n)))
            .ok_or_else(|| {
                format!("{text:?}: write length<N, length<=N, length>N, length>=N or length=N")
            })?;
            let steps = number
                .trim()
                .parse()
                .map_err(|_| format!("{text:?}: {number:?} is not a number of steps"))?;
            return Ok(Selector::Length(comparison, steps));
        }
        match text {
            "flagged" | "flagged=warnings" => return Ok(Selector::Flagged { errors_only: false }),
            "flagged=errors" => return Ok(Selector::Flagged { errors_only: true }),
            _ => {}
        }
        if let Some((key, value)) = text.split_once('=') {
            let (key, value) = (key.trim(), value.trim());
            if key.is_empty() || value.is_empty() {
                return Err(format!("{text:?}: write KEY=VALUE"));
            }
            return Ok(match key {
                "task" => Selector::Task(value.to_string()),
                _ => Selector::Field(key.to_string(), value.to_string()),
            });
        }
        parse_indices(text).map(Selector::Indices).map_err(|problem| {
            format!(
                "{text:?}: {problem} (give indices and ranges like 1,3,6-8, task=ID, length<N, KEY=VALUE or flagged)"
            )
        })
    }
}

impl std::fmt::Display for Selector {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Selector::Indices(ranges) => {
                let parts: Vec<String> = (ranges.iter())
                    .map(|r| match r.end - r.start {
                        1 => r.start.to_string(),
                        _ => format!("{}-{}", r.start, r.end - 1),
                    })
                    .collect();
                f.write_str(&parts.join(","))
            }
            Selector::Task(task) => write!(f, "task={task}"),
            Selector::Length(c, n) => {
                let op = match c {
                    Comparison::Less => "<",
                    Comparison::LessOrEqual => "<=",
                    Comparison::Greater => ">",
                    Comparison::GreaterOrEqual => ">=",
                    Comparison::Equal => "=",
                };
                write!(f, "length{op}{n}")
            }
            Selector::Field(key, value) => write!(f, "{key}={value}"),
            Selector::Flagged { errors_only: true } => f.write_str("flagged=errors"),
            Selector::Flagged { errors_only: false } => f.write_str("flagged"),
        }
    }
}

/// Whether a JSON value another tool stored reads as `text`.
fn value_is(value: &serde_json::Value, text: &str) -> bool {
    match value {
        serde_json::Value::String(s) => s == text,
        serde_json::Value::Bool(b) => text.parse::<bool>().is_ok_and(|t| t == *b),
        serde_json::Value::Number(n) => {
            n.to_string() == text
                || (text.parse::<f64>().ok()).is_some_and(|t| n.as_f64() == Some(t))
        }
        _ => false,
    }
}

impl Selector {
    /// Whether `episode` is one this selector names (`flagged`: validate's episodes).
    pub fn names(&self, episode: &Skimmed, flagged: &BTreeMap<u64, bool>) -> bool {
        let meta = &episode.meta;
        match self {
            Selector::Indices(ranges) => ranges.iter().any(|r| r.contains(&meta.index)),
            Selector::Task(task) => {
                meta.task_code.eq_ignore_ascii_case(task)
                    || meta.instruction.trim().eq_ignore_ascii_case(task.trim())
            }
            Selector::Length(comparison, steps) => comparison.holds(episode.steps, *steps),
            Selector::Field(key, value) => match key.as_str() {
                "success" => value.parse::<bool>().is_ok_and(|v| v == meta.success),
                "seed" => value.parse::<u64>().is_ok_and(|v| v == meta.seed),
                "level" => value.parse::<u8>().is_ok_and(|v| v == meta.level),
                "attempts" => value.parse::<u32>().is_ok_and(|v| v == meta.attempts),
                "instruction" => meta.instruction == *value,
                _ => meta.fields.get(key).is_some_and(|v| value_is(v, value)),
            },
            Selector::Flagged { errors_only } => flagged
                .get(&meta.index)
                .is_some_and(|error| *error || !errors_only),
        }
    }

    /// Whether this selector asks for validate's findings.
    pub fn wants_findings(&self) -> bool {
        matches!(self, Selector::Flagged { .. })
    }
}

/// `--split`: named parts of the kept episodes.
#[derive(Clone, Debug, PartialEq)]
pub enum Splits {
    /// `train=0.8,val=0.1,test=0.1`: shares of each task's episodes, drawn with the seed.
    Fractions(Vec<(String, f64)>),
    /// `train=0-79,val=80-89+95`: input episode indices per split (ranges joined by `+`).
    Indices(Vec<(String, Vec<Range<u64>>)>),
}

impl std::str::FromStr for Splits {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        let mut fractions = Vec::new();
        let mut indices = Vec::new();
        for part in text.split(',') {
            let (name, value) = part
                .split_once('=')
                .ok_or_else(|| format!("{part:?}: write NAME=SHARE or NAME=INDICES"))?;
            let name = name.trim();
            if !crate::export::paths::is_plain_name(name) {
                return Err(format!(
                    "{name:?}: a split's name is letters, digits, '_' and '-' (it names a folder)"
                ));
            }
            if fractions.iter().any(|(n, _)| n == name) || indices.iter().any(|(n, _)| n == name) {
                return Err(format!("the split {name:?} is named twice"));
            }
            let value = value.trim();
            if value.contains('.') {
                let share: f64 = value
                    .parse()
                    .map_err(|_| format!("{value:?} is not a share like 0.8"))?;
                if !(0.0..=1.0).contains(&share) {
                    return Err(format!("{name}={value}: a share is between 0 and 1"));
                }
                fractions.push((name.to_string(), share));
            } else {
                indices.push((name.to_string(), parse_indices(&value.replace('+', ","))?));
            }
        }
        match (fractions.is_empty(), indices.is_empty()) {
            (false, true) => {
                let sum: f64 = fractions.iter().map(|(_, f)| f).sum();
                if (sum - 1.0).abs() > 1e-6 {
                    return Err(format!(
                        "the shares add up to {sum}, not 1 (give every split its share, with a decimal point)"
                    ));
                }
                Ok(Splits::Fractions(fractions))
            }
            (true, false) => Ok(Splits::Indices(indices)),
            _ => Err(
                "give every split a share (0.8, with a decimal point) or every split its indices (0-79), not both"
                    .into(),
            ),
        }
    }
}

impl std::fmt::Display for Splits {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let parts: Vec<String> = match self {
            Splits::Fractions(shares) => shares.iter().map(|(n, x)| format!("{n}={x}")).collect(),
            Splits::Indices(splits) => (splits.iter())
                .map(|(n, ranges)| {
                    let text = Selector::Indices(ranges.clone()).to_string();
                    format!("{n}={}", text.replace(',', "+"))
                })
                .collect(),
        };
        f.write_str(&parts.join(","))
    }
}

/// The result of [`choose`]: the outputs to write, and what was left.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Chosen {
    /// Each output: its split's name (None: the one dataset) and the input episodes it holds,
    /// in its order.
    pub outputs: Vec<(Option<String>, Vec<u64>)>,
    /// Input episodes kept, in input order.
    pub kept: Vec<u64>,
    /// Input episodes left out.
    pub dropped: Vec<u64>,
    /// What the user should hear (a selector that named no episode).
    pub notes: Vec<String>,
}

/// What [`choose`] is asked.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Selection {
    pub keep: Vec<Selector>,
    pub drop: Vec<Selector>,
    pub splits: Option<Splits>,
    /// The seed of fractional splits.
    pub seed: u64,
}

/// Chooses the episodes of `listed` (every input episode, in order) the selection keeps and
/// places them in outputs: an episode is kept when any `keep` selector names it (or none is
/// given) and no `drop` selector does. `flagged` holds validate's episodes for `flagged`.
/// A selector naming a field no episode has is refused by name.
pub fn choose(
    listed: &[Skimmed],
    selection: &Selection,
    flagged: &BTreeMap<u64, bool>,
) -> Result<Chosen, String> {
    let mut chosen = Chosen::default();
    for (word, selectors) in [("--keep", &selection.keep), ("--drop", &selection.drop)] {
        for selector in selectors {
            if let Selector::Field(key, _) = selector
                && !PROVENANCE.contains(&key.as_str())
                && !listed.iter().any(|e| e.meta.fields.contains_key(key))
            {
                let mut keys: Vec<&str> = PROVENANCE.to_vec();
                keys.extend(
                    listed
                        .iter()
                        .flat_map(|e| e.meta.fields.keys().map(String::as_str)),
                );
                keys.sort();
                keys.dedup();
                return Err(format!(
                    "{word} {selector}: no episode has a field {key:?} (fields: task, length, {})",
                    keys.join(", ")
                ));
            }
            if !listed.iter().any(|e| selector.names(e, flagged)) {
                chosen
                    .notes
                    .push(format!("{word} {selector} names no episode"));
            }
        }
    }
    for episode in listed {
        let index = episode.meta.index;
        let kept = (selection.keep.is_empty()
            || selection.keep.iter().any(|s| s.names(episode, flagged)))
            && !selection.drop.iter().any(|s| s.names(episode, flagged));
        if kept {
            chosen.kept.push(index);
        } else {
            chosen.dropped.push(index);
        }
    }
    chosen.outputs = match &selection.splits {
        None => vec![(None, chosen.kept.clone())],
        Some(Splits::Indices(splits)) => {
            let mut placed: BTreeMap<u64, &str> = BTreeMap::new();
            let mut outputs = Vec::new();
            for (name, ranges) in splits {
                let members: Vec<u64> = (chosen.kept.iter().copied())
                    .filter(|i| ranges.iter().any(|r| r.contains(i)))
                    .collect();
                for i in &members {
                    if let Some(other) = placed.insert(*i, name) {
                        return Err(format!(
                            "--split: episode {i} is in both {other:?} and {name:?}"
                        ));
                    }
                }
                outputs.push((Some(name.clone()), members));
            }
            outputs
        }
        Some(Splits::Fractions(shares)) => stratified(listed, &chosen.kept, shares, selection.seed),
    };
    Ok(chosen)
}

/// Fractional splits of `kept`: per task (its id, else its instruction), the episodes
/// shuffled with the seed's stream for the task and cut at the shares (largest remainders
/// get the odd episodes, earlier splits first on ties); each split in input order.
fn stratified(
    listed: &[Skimmed],
    kept: &[u64],
    shares: &[(String, f64)],
    seed: u64,
) -> Vec<(Option<String>, Vec<u64>)> {
    let kept: std::collections::BTreeSet<u64> = kept.iter().copied().collect();
    let mut by_task: BTreeMap<String, Vec<u64>> = BTreeMap::new();
    for episode in listed.iter().filter(|e| kept.contains(&e.meta.index)) {
        let key = if episode.meta.task_code.is_empty() {
            episode.meta.instruction.clone()
        } else {
            episode.meta.task_code.clone()
        };
        by_task.entry(key).or_default().push(episode.meta.index);
    }
    let mut members: Vec<Vec<u64>> = vec![Vec::new(); shares.len()];
    for (task, mut episodes) in by_task {
        let mut rng = crate::rng::SplitMix64::stream(seed, &format!("edit/split/{task}"));
        for i in (1..episodes.len()).rev() {
            let j = (rng.next_u64() % (i as u64 + 1)) as usize;
            episodes.swap(i, j);
        }
        let n = episodes.len();
        let exact: Vec<f64> = shares.iter().map(|(_, f)| f * n as f64).collect();
        let mut counts: Vec<usize> = exact.iter().map(|x| x.floor() as usize).collect();
        let mut order: Vec<usize> = (0..shares.len()).collect();
        order.sort_by(|a, b| {
            let (ra, rb) = (exact[*a] - exact[*a].floor(), exact[*b] - exact[*b].floor());
            rb.total_cmp(&ra).then(a.cmp(b))
        });
        let mut left = n.saturating_sub(counts.iter().sum());
        for split in order.into_iter().cycle().take(shares.len() * 2) {
            if left == 0 {
                break;
            }
            if shares[split].1 > 0.0 {
                counts[split] += 1;
                left -= 1;
            }
        }
        let mut from = 0;
        for (split, count) in counts.into_iter().enumerate() {
            let to = (from + count).min(n);
            members[split].extend_from_slice(&episodes[from..to]);
            from = to;
        }
    }
    shares
        .iter()
        .zip(members)
        .map(|((name, _), mut m)| {
            m.sort_unstable();
            (Some(name.clone()), m)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::episode::EpisodeMeta;

    fn listed(tasks: &[&str], lengths: &[u64]) -> Vec<Skimmed> {
        (0..lengths.len())
            .map(|i| Skimmed {
                meta: EpisodeMeta {
                    task_code: tasks[i % tasks.len()].into(),
                    seed: i as u64 * 10,
                    success: i % 3 != 0,
                    ..EpisodeMeta::foreign(i as u64, format!("do {}", tasks[i % tasks.len()]))
                },
                steps: lengths[i],
            })
            .collect()
    }

    #[test]
    fn selectors_parse_and_print_back() {
        for text in [
            "1,3,6-8",
            "task=T1-1",
            "length<50",
            "length>=10",
            "success=false",
            "flagged",
            "flagged=errors",
        ] {
            let selector: Selector = text.parse().unwrap();
            assert_eq!(selector.to_string(), text);
        }
        assert_eq!(
            "1,3,6-8".parse::<Selector>().unwrap(),
            Selector::Indices(vec![1..2, 3..4, 6..9])
        );
        assert!("8-6".parse::<Selector>().is_err());
        assert!("length~3".parse::<Selector>().is_err());
        assert!("one".parse::<Selector>().is_err());
    }

    #[test]
    fn keep_and_drop_compose_and_unknown_fields_are_refused() {
        let episodes = listed(&["T1-1", "T1-2"], &[10, 60, 70, 20, 90, 100]);
        let none = BTreeMap::new();
        let selection = Selection {
            keep: vec!["task=t1-1".parse().unwrap(), "5".parse().unwrap()],
            drop: vec!["length<50".parse().unwrap()],
            ..Default::default()
        };
        let chosen = choose(&episodes, &selection, &none).unwrap();
        assert_eq!(chosen.kept, [2, 4, 5]);
        assert_eq!(chosen.dropped, [0, 1, 3]);
        let by_success = Selection {
            drop: vec!["success=false".parse().unwrap()],
            ..Default::default()
        };
        assert_eq!(
            choose(&episodes, &by_success, &none).unwrap().kept,
            [1, 2, 4, 5]
        );
        let flagged = BTreeMap::from([(1, false), (2, true)]);
        let lint = Selection {
            drop: vec!["flagged=errors".parse().unwrap()],
            ..Default::default()
        };
        assert_eq!(choose(&episodes, &lint, &flagged).unwrap().dropped, [2]);
        let unknown = Selection {
            keep: vec!["operator=ann".parse().unwrap()],
            ..Default::default()
        };
        let problem = choose(&episodes, &unknown, &none).unwrap_err();
        assert!(
            problem.contains("operator") && problem.contains("success"),
            "{problem}"
        );
    }

    #[test]
    fn fractional_splits_are_stratified_seeded_and_complete() {
        let episodes = listed(&["T1-1", "T1-2", "T2-1"], &[50; 60]);
        let selection = |seed| Selection {
            splits: Some("train=0.8,val=0.1,test=0.1".parse().unwrap()),
            seed,
            ..Default::default()
        };
        let none = BTreeMap::new();
        let chosen = choose(&episodes, &selection(0), &none).unwrap();
        let sizes: Vec<usize> = chosen.outputs.iter().map(|(_, m)| m.len()).collect();
        assert_eq!(sizes, [48, 6, 6]);
        for (_, members) in &chosen.outputs {
            for task in 0..3u64 {
                let of_task = members.iter().filter(|i| *i % 3 == task).count();
                assert_eq!(of_task * 60, members.len() * 20, "stratified by task");
            }
        }
        let mut all: Vec<u64> = chosen.outputs.iter().flat_map(|(_, m)| m.clone()).collect();
        all.sort_unstable();
        assert_eq!(all, (0..60).collect::<Vec<_>>());
        assert_eq!(choose(&episodes, &selection(0), &none).unwrap(), chosen);
        assert_ne!(choose(&episodes, &selection(1), &none).unwrap(), chosen);
        assert!("train=0.8,val=0.1".parse::<Splits>().is_err());
        assert!("train=0.5,val=1-3".parse::<Splits>().is_err());
        assert!("../x=0.5,val=0.5".parse::<Splits>().is_err());
        let listed_splits = Selection {
            splits: Some("train=0-9+20-59,recovery=10-19".parse().unwrap()),
            ..Default::default()
        };
        let chosen = choose(&episodes, &listed_splits, &none).unwrap();
        assert_eq!(chosen.outputs[1].1, (10..20).collect::<Vec<_>>());
        assert_eq!(chosen.outputs[0].1.len(), 50);
    }
}
