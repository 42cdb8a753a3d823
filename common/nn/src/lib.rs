//! The f32 neural-network core of MBPO.
//!
//! Design, in one paragraph: a network is an architecture ([`Mlp`], [`EnsembleMlp`]) that owns no
//! numbers. Its parameters live in one contiguous `&[f32]` described by a [`ParamLayout`], which
//! is exactly what crosses shared memory, what Adam updates, and what a checkpoint stores.
//! Activations live in a cache ([`MlpCache`]) sized once for a batch, so forward and backward
//! allocate nothing per call. Every GEMM is one call into faer ([`gemm`]; output widths that are not
//! a multiple of 16 go through a kernel with faer's results), single-threaded; a caller that wants
//! more cores splits its batch over a [`WorkerPool`].
//!
//! ```
//! use mbpo_nn::{Activation, Init, Mlp, MlpCache};
//! let net = Mlp::new(&[3, 16, 2], Activation::Relu, Activation::Identity);
//! let mut params = vec![0.0; net.num_params()];
//! net.init(&mut params, Init::TorchDefault, &mut mbpo_core::stream(0, "doc", 0));
//! let mut cache = MlpCache::new(&net, 4);
//! let y = net.forward(&params, &[0.1; 12], 4, &mut cache);
//! assert_eq!(y.len(), 8);
//! ```
#![warn(missing_docs)]

pub mod activation;
pub mod adam;
pub mod bench;
pub mod ensemble;
pub mod gemm;
pub mod init;
pub mod layout;
pub mod math;
pub mod mlp;
pub mod norm;
pub mod ops;
pub mod pool;
pub mod simd;
pub mod subnormal;

pub use activation::Activation;
pub use adam::{Adam, AdamConfig, AdamState, WeightDecay};
pub use ensemble::{EnsembleCache, EnsembleMlp};
pub use init::Init;
pub use layout::{ParamFile, ParamLayout, ParamLoadError};
pub use mlp::{Mlp, MlpCache};
pub use pool::WorkerPool;
pub use subnormal::FlushSubnormals;
