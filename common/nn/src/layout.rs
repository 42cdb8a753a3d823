//! Named layouts of flat parameter vectors, their hash, and the parameter file format.
//!
//! A network's parameters are one contiguous `[f32]`. The [`ParamLayout`] names every tensor in
//! it (`l0.w` of shape `[17, 256]` at offset 0, ...). Its 64-bit [`ParamLayout::hash`] is what a
//! receiver compares before trusting a weight broadcast or a checkpoint: two networks agree on
//! the hash exactly when they agree on every name, shape and order.

use serde::{Deserialize, Serialize};
use std::fmt::Write as _;
use std::ops::Range;

/// One named tensor inside a flat parameter vector.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ParamEntry {
    /// Name, e.g. `critic1.l0.w`.
    pub name: String,
    /// Shape, row-major.
    pub shape: Vec<usize>,
    /// Offset of the first element in the flat vector.
    pub offset: usize,
}

impl ParamEntry {
    /// Number of elements.
    pub fn len(&self) -> usize {
        self.shape.iter().product()
    }
    /// True for a zero-sized tensor.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// The range of this tensor in the flat vector.
    pub fn range(&self) -> Range<usize> {
        self.offset..self.offset + self.len()
    }
}

/// The ordered list of named tensors making up a flat parameter vector.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct ParamLayout {
    entries: Vec<ParamEntry>,
    len: usize,
}

impl ParamLayout {
    /// An empty layout.
    pub fn new() -> Self {
        Self::default()
    }

    /// Append a tensor; returns its range in the flat vector.
    pub fn push(&mut self, name: impl Into<String>, shape: &[usize]) -> Range<usize> {
        let entry = ParamEntry {
            name: name.into(),
            shape: shape.to_vec(),
            offset: self.len,
        };
        self.len += entry.len();
        let r = entry.range();
        self.entries.push(entry);
        r
    }

    /// Append every tensor of `other` with `prefix.` before its name; returns the range covered.
    pub fn extend_prefixed(&mut self, prefix: &str, other: &ParamLayout) -> Range<usize> {
        let start = self.len;
        for e in &other.entries {
            self.push(format!("{prefix}.{}", e.name), &e.shape);
        }
        start..self.len
    }

    /// Total number of parameters.
    pub fn len(&self) -> usize {
        self.len
    }
    /// True when there are no parameters.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
    /// The tensors in order.
    pub fn entries(&self) -> &[ParamEntry] {
        &self.entries
    }
    /// The tensor called `name`.
    pub fn get(&self, name: &str) -> Option<&ParamEntry> {
        self.entries.iter().find(|e| e.name == name)
    }

    /// One line per tensor: `name [shape]`; used in error messages.
    pub fn describe(&self) -> String {
        let mut s = String::new();
        for e in &self.entries {
            let _ = write!(s, "{} {:?}; ", e.name, e.shape);
        }
        s.truncate(s.trim_end_matches("; ").len());
        s
    }

    /// FNV-1a over every name and shape, in order.
    pub fn hash(&self) -> u64 {
        let mut text = String::new();
        for e in &self.entries {
            let _ = write!(text, "{}:{:?};", e.name, e.shape);
        }
        mbpo_core::rng::fnv1a(text.as_bytes())
    }
}

/// Version of the [`ParamFile`] encoding.
pub const PARAM_FILE_VERSION: u32 = 1;

/// A serialized parameter vector with the layout it was written for (serde + bincode).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ParamFile {
    /// [`PARAM_FILE_VERSION`] at write time.
    pub version: u32,
    /// [`ParamLayout::hash`] of the writer's network.
    pub layout_hash: u64,
    /// The writer's layout, so a mismatch can say what differs.
    pub layout: ParamLayout,
    /// The flat parameters.
    pub params: Vec<f32>,
}

/// Why a parameter file could not be loaded.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ParamLoadError {
    /// The bytes are not a parameter file (truncated, corrupted, or another format).
    #[error("not a valid parameter file ({0}); was it written by `ParamFile::to_bytes`, and is it complete?")]
    Decode(String),
    /// Written by a different version of the format.
    #[error("parameter file format version {found}, this build reads version {expected}")]
    Version {
        /// Version this build reads.
        expected: u32,
        /// Version in the file.
        found: u32,
    },
    /// The file's network has another architecture than the receiving one.
    #[error("parameter layout mismatch: this network has layout hash {expected:#018x} ({expected_layout}), the file has {found:#018x} ({found_layout}); load it into a network of the same architecture")]
    LayoutMismatch {
        /// Hash of the receiving network's layout.
        expected: u64,
        /// Hash stored in the file.
        found: u64,
        /// Receiving layout, described.
        expected_layout: String,
        /// File's layout, described.
        found_layout: String,
    },
    /// The number of parameters disagrees with the layout.
    #[error("parameter file holds {found} values but its layout needs {expected}")]
    Length {
        /// Values the layout needs.
        expected: usize,
        /// Values present.
        found: usize,
    },
}

impl ParamFile {
    /// Package `params` written for `layout`.
    pub fn new(layout: &ParamLayout, params: &[f32]) -> Self {
        assert_eq!(
            layout.len(),
            params.len(),
            "params do not match their layout"
        );
        Self {
            version: PARAM_FILE_VERSION,
            layout_hash: layout.hash(),
            layout: layout.clone(),
            params: params.to_vec(),
        }
    }

    /// Encode with bincode (standard configuration, little-endian).
    pub fn to_bytes(&self) -> Vec<u8> {
        bincode::serde::encode_to_vec(self, bincode::config::standard())
            .expect("encoding a ParamFile into memory cannot fail")
    }

    /// Decode bytes and check them against the receiving network's `layout`.
    pub fn from_bytes(bytes: &[u8], layout: &ParamLayout) -> Result<Self, ParamLoadError> {
        let (file, used): (ParamFile, usize) =
            bincode::serde::decode_from_slice(bytes, bincode::config::standard())
                .map_err(|e| ParamLoadError::Decode(e.to_string()))?;
        if used != bytes.len() {
            return Err(ParamLoadError::Decode(format!(
                "{} trailing bytes after the parameters",
                bytes.len() - used
            )));
        }
        if file.version != PARAM_FILE_VERSION {
            return Err(ParamLoadError::Version {
                expected: PARAM_FILE_VERSION,
                found: file.version,
            });
        }
        if file.layout_hash != layout.hash() || file.layout != *layout {
            return Err(ParamLoadError::LayoutMismatch {
                expected: layout.hash(),
                found: file.layout_hash,
                expected_layout: layout.describe(),
                found_layout: file.layout.describe(),
            });
        }
        if file.params.len() != layout.len() {
            return Err(ParamLoadError::Length {
                expected: layout.len(),
                found: file.params.len(),
            });
        }
        Ok(file)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn layout(width: usize) -> ParamLayout {
        let mut l = ParamLayout::new();
        l.push("l0.w", &[3, width]);
        l.push("l0.b", &[width]);
        l
    }

    #[test]
    fn offsets_and_hash() {
        let l = layout(4);
        assert_eq!(l.len(), 16);
        assert_eq!(l.get("l0.b").unwrap().range(), 12..16);
        assert_eq!(l.hash(), layout(4).hash());
        assert_ne!(l.hash(), layout(5).hash());
        let mut renamed = ParamLayout::new();
        renamed.push("l0.weight", &[3, 4]);
        renamed.push("l0.b", &[4]);
        assert_ne!(l.hash(), renamed.hash());
    }

    #[test]
    fn file_round_trip_is_exact() {
        let l = layout(4);
        let params: Vec<f32> = (0..16).map(|i| (i as f32).sin() * 1e-3).collect();
        let bytes = ParamFile::new(&l, &params).to_bytes();
        let back = ParamFile::from_bytes(&bytes, &l).unwrap();
        assert_eq!(back.params, params);
    }

    #[test]
    fn mismatched_layout_is_rejected_with_both_layouts_named() {
        let bytes = ParamFile::new(&layout(4), &[0.0; 16]).to_bytes();
        let err = ParamFile::from_bytes(&bytes, &layout(5)).unwrap_err();
        let msg = err.to_string();
        assert!(matches!(err, ParamLoadError::LayoutMismatch { .. }));
        assert!(
            msg.contains("l0.w [3, 5]") && msg.contains("l0.w [3, 4]"),
            "{msg}"
        );
    }

    #[test]
    fn truncated_or_padded_bytes_are_rejected() {
        let bytes = ParamFile::new(&layout(4), &[1.0; 16]).to_bytes();
        let err = ParamFile::from_bytes(&bytes[..bytes.len() - 3], &layout(4)).unwrap_err();
        assert!(matches!(err, ParamLoadError::Decode(_)), "{err}");
        let mut padded = bytes.clone();
        padded.push(0);
        let err = ParamFile::from_bytes(&padded, &layout(4)).unwrap_err();
        assert!(matches!(err, ParamLoadError::Decode(_)), "{err}");
    }
}
