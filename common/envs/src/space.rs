//! Box spaces, and the parts of a flattened Dict observation.

use serde::{Deserialize, Serialize};

/// One part of a Dict observation, in the order the flat observation holds them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ObsPart {
    /// The Dict key.
    pub key: String,
    /// Its shape (the flat observation holds the product of it, row-major).
    pub shape: Vec<usize>,
}

/// A box `[low, high]` per dimension (Gymnasium's `Box`).
#[derive(Debug, Clone, PartialEq)]
pub struct BoxSpace {
    /// Lower bound per dimension.
    pub low: Vec<f32>,
    /// Upper bound per dimension.
    pub high: Vec<f32>,
}

impl BoxSpace {
    /// A box from its bounds (same lengths).
    pub fn new(low: Vec<f32>, high: Vec<f32>) -> Self {
        assert_eq!(low.len(), high.len(), "box bounds differ in length");
        Self { low, high }
    }
    /// Number of dimensions.
    pub fn dim(&self) -> usize {
        self.low.len()
    }
}
