//! Box spaces.

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
