//! Every role's service loop, generic over the transport: a binary under `services/` runs one
//! of them in its own process (`ipc::Service`); a test can run them all as threads of one
//! process (`local::Service`).

mod acting;
pub mod actor;
pub mod learner;
pub mod model_trainer;
pub mod planning;
pub mod rollout;
