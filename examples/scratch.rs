use surgvla::collect::record::{attempt_seed, run_expert, verify_replay};
use surgvla::episode::GripperEncoding;
use surgvla::policy::ExpertLibrary;
use surgvla::task::{TaskConfig, TaskId};
fn main() {
    let lib = ExpertLibrary::builtin().unwrap();
    let n: u64 = std::env::args().nth(1).map(|s| s.parse().unwrap()).unwrap_or(50);
    let only: Option<TaskId> = std::env::args().nth(2).map(|s| s.parse().unwrap());
    for task in TaskId::ALL {
        if only.is_some_and(|t| t != task) { continue; }
        let (mut ok, mut rep, mut steps) = (0, 0, 0);
        let mut reasons = std::collections::BTreeMap::new();
        for k in 0..n {
            let seed = attempt_seed(0, task, k, 0);
            let inst = task.instance(seed, &TaskConfig::default());
            let run = run_expert(&inst, lib.plan(task).unwrap(), task.step_limit(), GripperEncoding::Continuous).unwrap();
            steps += run.actions.len();
            if run.verdict.success {
                ok += 1;
                let v = verify_replay(&inst, &run.actions, GripperEncoding::Continuous);
                if v.success { rep += 1 } else { *reasons.entry(format!("replay: {}", v.reason)).or_insert(0) += 1; }
            } else {
                let r = run.verdict.reason.clone();
                if reasons.len() < 6 || only.is_some() { println!("  k={k} {r}"); }
                *reasons.entry(r.split(' ').take(3).collect::<Vec<_>>().join(" ")).or_insert(0) += 1;
            }
        }
        println!("{} expert {}/{} replay {} mean steps {:.1} {:?}", task.code(), ok, n, rep, steps as f64 / n as f64, reasons);
    }
}
