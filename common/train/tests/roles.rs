//! The pipeline roles act only with a policy they received: the zeros a role starts with are
//! not the learner's version 0 (its random initialisation), so an actor or rollout generator
//! that waited for "version >= 0" would otherwise act with them before the learner's first
//! snapshot arrived.

use mbpo_train::roles::{ActorRole, LearnerRole, RolloutRole};

mod support;
use support::small_mbpo;

#[test]
fn a_new_or_restored_role_has_no_policy_until_a_snapshot_arrives() {
    let cfg = small_mbpo(400);
    let learner = LearnerRole::new(&cfg, 3, 1);
    let v0 = learner.policy();
    assert_eq!(v0.version, 0);
    assert!(
        v0.params.iter().any(|&p| p != 0.0),
        "the learner's version 0 is its random initialisation"
    );

    let mut actor = ActorRole::new(&cfg, 0).unwrap();
    assert!(
        !actor.has_policy(0),
        "placeholder zeros counted as version 0"
    );
    actor.set_policy(&v0);
    assert!(actor.has_policy(0) && !actor.has_policy(1));
    let mut restored = ActorRole::new(&cfg, 0).unwrap();
    restored.restore(actor.checkpoint()).unwrap();
    assert!(
        !restored.has_policy(0),
        "a restored actor must wait for the learner's republished version"
    );
    restored.set_policy_params(&v0.params, 7);
    assert!(restored.has_policy(7) && !restored.has_policy(8));

    let mut rollouts = RolloutRole::new(&cfg, 3, 1).unwrap();
    assert!(
        !rollouts.has_policy(0),
        "placeholder zeros counted as version 0"
    );
    rollouts.set_policy(&v0);
    assert!(rollouts.has_policy(0) && !rollouts.has_policy(1));
    let mut restored = RolloutRole::new(&cfg, 3, 1).unwrap();
    restored.restore(rollouts.checkpoint()).unwrap();
    assert!(!restored.has_policy(0));
}
