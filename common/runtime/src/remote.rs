//! Which roles can run on another host, behind the gateways (`mbpo_net`).
//!
//! A gateway carries channels, not roles: on the head it stands in for a remote role's ports
//! (it subscribes what the role subscribes and publishes what the role publishes), on the
//! worker it stands in for the head's side. What it carries is fixed here, once:
//! * to the worker: the weights its roles act with (latest value) and control commands;
//! * from the worker: real transitions, reports and control messages (the evaluator's
//!   acknowledgements in lockstep), each a reliable stream.
//!
//! So any role whose channels are within those runs remotely: the actors (`--remote-actors`)
//! and the evaluator (`--remote-roles evaluator`). A role that consumes real or imagined
//! transitions, or publishes weights, does not yet: it is refused by name with the channel the
//! gateways do not carry.

use mbpo_wire::Channel;

use crate::pipeline::{PipelineSpec, RoleKind};

/// Channels a gateway carries from the head to a worker's roles.
pub const TO_WORKER: [Channel; 3] = [Channel::Policy, Channel::Model, Channel::Control];

/// Channels a gateway carries from a worker's roles to the head.
pub const FROM_WORKER: [Channel; 3] = [Channel::Real, Channel::Stats, Channel::Control];

/// Whether role `kind` of `pipeline` can run behind the gateways, or why not (the channel they
/// do not carry). The weights are the pipeline's actors' (one kind crosses per run).
pub fn can_run_remotely(pipeline: &PipelineSpec, kind: RoleKind) -> Result<(), String> {
    let row = kind.row();
    let weights = weights_channel(pipeline);
    let name = kind.name(0);
    if let Some(c) = row.subscribes.iter().find(|c| !TO_WORKER.contains(c)) {
        return Err(format!(
            "the {name} receives {c}, which the gateways do not carry to a worker (they carry {})",
            names(&TO_WORKER)
        ));
    }
    if let Some(c) = row.publishes.iter().find(|c| !FROM_WORKER.contains(c)) {
        return Err(format!(
            "the {name} publishes {c}, which the gateways do not carry from a worker (they carry {})",
            names(&FROM_WORKER)
        ));
    }
    let other = [Channel::Policy, Channel::Model]
        .into_iter()
        .find(|c| *c != weights);
    match other.filter(|c| row.subscribes.contains(c)) {
        Some(c) => Err(format!(
            "the {name} receives {c} weights, but a worker of this run gets only {weights}"
        )),
        None => Ok(()),
    }
}

/// The weights channel a run's gateways carry: what its actors act with.
pub fn weights_channel(pipeline: &PipelineSpec) -> Channel {
    pipeline.actor_weights().channel()
}

/// The roles named `names` (`mbpo run --remote-roles`: process names such as `evaluator`) of
/// `pipeline`, each checked to run behind the gateways; an error names the role and why.
pub fn remote_services(pipeline: &PipelineSpec, names: &[String]) -> Result<Vec<RoleKind>, String> {
    let mut kinds = Vec::new();
    for name in names {
        let found = pipeline.services.iter().find(|k| k.name(0) == *name);
        let Some(&kind) = found else {
            let known: Vec<String> = pipeline.services.iter().map(|k| k.name(0)).collect();
            let hint = match name.starts_with("actor") {
                true => " (actors run remotely with --remote-actors N)",
                false => "",
            };
            return Err(format!(
                "--remote-roles {name}: the {} run has no role of that name; its roles are {}{hint}",
                pipeline.algo,
                known.join(", ")
            ));
        };
        can_run_remotely(pipeline, kind).map_err(|why| format!("--remote-roles {name}: {why}"))?;
        if !kinds.contains(&kind) {
            kinds.push(kind);
        }
    }
    Ok(kinds)
}

fn names(channels: &[Channel]) -> String {
    let n: Vec<&str> = channels.iter().map(|c| c.suffix()).collect();
    n.join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;
    use mbpo_train::Algo;

    fn mbpo() -> &'static PipelineSpec {
        crate::pipeline::spec(Algo::MBPO).unwrap()
    }

    #[test]
    fn actors_and_evaluators_run_remotely_the_learning_roles_do_not() {
        for algo in [Algo::MBPO, Algo::MPC] {
            let p = crate::pipeline::spec(algo).unwrap();
            for kind in p.roles(1).iter().map(|r| r.kind) {
                let remote = can_run_remotely(p, kind);
                assert_eq!(
                    remote.is_ok(),
                    kind.steps_an_env(),
                    "{} {kind:?}: {remote:?}",
                    p.algo
                );
            }
        }
        let why = can_run_remotely(mbpo(), RoleKind::Learner).unwrap_err();
        assert!(why.contains("the learner receives real"), "{why}");
    }

    #[test]
    fn remote_roles_are_named_as_their_processes() {
        let ev = remote_services(mbpo(), &["evaluator".into(), "evaluator".into()]);
        assert_eq!(ev, Ok(vec![RoleKind::Evaluator]));
        let mpc = crate::pipeline::spec(Algo::MPC).unwrap();
        let ev = remote_services(mpc, &["evaluator".into()]);
        assert_eq!(ev, Ok(vec![RoleKind::PlanningEvaluator]));
        let err = remote_services(mbpo(), &["model-trainer".into()]).unwrap_err();
        assert!(
            err.contains("--remote-roles model-trainer: the model-trainer receives real"),
            "{err}"
        );
        let err = remote_services(mbpo(), &["actor-1".into()]).unwrap_err();
        assert!(
            err.contains("no role of that name") && err.contains("--remote-actors"),
            "{err}"
        );
        let err = remote_services(mpc, &["learner".into()]).unwrap_err();
        assert!(err.contains("model-trainer, evaluator"), "{err}");
    }
}
