//! A minimal TensorBoard event-file writer: scalars only, no dependencies.
//!
//! Why hand-written: the crates that exist (`tensorboard-rs`, `syntaxdot-summary`) are
//! unmaintained since 2022 and pull in old protobuf stacks (`protobuf` 2 with a RustSec
//! advisory, `image` 0.23; `prost` 0.9). Scalars need only two tiny formats:
//!
//! * **TFRecord framing**, one record per event: `u64` length (little-endian), masked
//!   CRC-32C of those 8 bytes, the data, masked CRC-32C of the data.
//! * **A protobuf `Event`** (`tensorflow/core/util/event.proto`), of which we encode
//!   `wall_time = 1` (double), `step = 2` (int64), `file_version = 3` (string),
//!   `summary = 5` (`Summary { value = 1 repeated Value { tag = 1 string, simple_value = 2
//!   float } }`) and `session_log = 7` (`SessionLog { status = 1 enum, START = 1 }`; field 6
//!   is the deprecated `log_message`).
//!
//! A file is `<dir>/events.out.tfevents.<unix secs>.<hostname>.<pid>` and starts with a
//! `file_version = "brain.Event:2"` event. Every [`EventWriter::add_scalars`] call is one event
//! and is flushed, so a running TensorBoard shows the run as it goes. A writer never opens an
//! existing file: a resumed run writes a new file with a `SessionLog START` at the resume step,
//! which tells TensorBoard to drop the points earlier files have at or after that step (they
//! belong to the abandoned future of the checkpoint). TensorBoard's server
//! (`plugin_event_accumulator`) takes the *first* START of a run as its beginning and purges
//! only on later ones, so a fresh run starts with a START at step 0 too (`RunDir` does both).

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

/// CRC-32C (Castagnoli, reflected polynomial 0x82F63B78), the checksum TFRecord uses.
pub mod crc32c {
    /// Byte-at-a-time lookup table, computed at compile time.
    const TABLE: [u32; 256] = {
        let mut table = [0u32; 256];
        let mut i = 0;
        while i < 256 {
            let mut crc = i as u32;
            let mut bit = 0;
            while bit < 8 {
                crc = if crc & 1 != 0 {
                    (crc >> 1) ^ 0x82F6_3B78
                } else {
                    crc >> 1
                };
                bit += 1;
            }
            table[i] = crc;
            i += 1;
        }
        table
    };

    /// CRC-32C of `data`.
    pub fn checksum(data: &[u8]) -> u32 {
        let mut crc = !0u32;
        for &b in data {
            crc = TABLE[((crc ^ b as u32) & 0xff) as usize] ^ (crc >> 8);
        }
        !crc
    }

    /// TFRecord's masked CRC: rotate right by 15 and add a constant, so that a CRC stored
    /// inside data that is itself checksummed does not weaken the outer checksum.
    pub fn masked(data: &[u8]) -> u32 {
        checksum(data).rotate_right(15).wrapping_add(0xa282_ead8)
    }
}

/// Protobuf wire types used here.
const VARINT: u8 = 0;
const FIXED64: u8 = 1;
const LEN: u8 = 2;
const FIXED32: u8 = 5;

/// `SessionLog.status = START`.
const SESSION_START: u64 = 1;

fn put_varint(out: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

fn put_key(out: &mut Vec<u8>, field: u8, wire: u8) {
    out.push((field << 3) | wire);
}

fn put_bytes(out: &mut Vec<u8>, field: u8, bytes: &[u8]) {
    put_key(out, field, LEN);
    put_varint(out, bytes.len() as u64);
    out.extend_from_slice(bytes);
}

/// The fields every event starts with: `wall_time` and `step`.
fn put_event_header(out: &mut Vec<u8>, wall_time: f64, step: i64) {
    put_key(out, 1, FIXED64);
    out.extend_from_slice(&wall_time.to_le_bytes());
    put_key(out, 2, VARINT);
    // int64 is encoded as the two's-complement u64 (negative steps take 10 bytes).
    put_varint(out, step as u64);
}

/// Encode `Event { wall_time, step, file_version }`.
pub fn encode_file_version(out: &mut Vec<u8>, wall_time: f64, version: &str) {
    put_event_header(out, wall_time, 0);
    put_bytes(out, 3, version.as_bytes());
}

/// Encode `Event { wall_time, step, summary { value: [{tag, simple_value}, ...] } }`.
pub fn encode_scalars(out: &mut Vec<u8>, wall_time: f64, step: i64, values: &[(&str, f32)]) {
    put_event_header(out, wall_time, step);
    // Summary.value entries: tag (field 1) + simple_value (field 2, fixed32).
    let value_len = |tag: &str| 1 + varint_len(tag.len() as u64) + tag.len() + 1 + 4;
    let summary_len: usize = values
        .iter()
        .map(|(tag, _)| {
            let n = value_len(tag);
            1 + varint_len(n as u64) + n
        })
        .sum();
    put_key(out, 5, LEN);
    put_varint(out, summary_len as u64);
    for (tag, v) in values {
        put_key(out, 1, LEN);
        put_varint(out, value_len(tag) as u64);
        put_bytes(out, 1, tag.as_bytes());
        put_key(out, 2, FIXED32);
        out.extend_from_slice(&v.to_le_bytes());
    }
}

/// Encode `Event { wall_time, step, session_log { status: START } }`.
pub fn encode_session_start(out: &mut Vec<u8>, wall_time: f64, step: i64) {
    put_event_header(out, wall_time, step);
    put_key(out, 7, LEN);
    put_varint(out, 2);
    put_key(out, 1, VARINT);
    put_varint(out, SESSION_START);
}

fn varint_len(mut v: u64) -> usize {
    let mut n = 1;
    while v >= 0x80 {
        v >>= 7;
        n += 1;
    }
    n
}

/// Frame `data` as one TFRecord into `out`.
pub fn frame_record(out: &mut impl Write, data: &[u8]) -> std::io::Result<()> {
    let len = (data.len() as u64).to_le_bytes();
    out.write_all(&len)?;
    out.write_all(&crc32c::masked(&len).to_le_bytes())?;
    out.write_all(data)?;
    out.write_all(&crc32c::masked(data).to_le_bytes())
}

/// The host name for the file name (`/proc/sys/kernel/hostname`, else `localhost`), with
/// anything that is not safe in a file name replaced.
fn hostname() -> String {
    let raw = std::fs::read_to_string("/proc/sys/kernel/hostname")
        .or_else(|_| std::fs::read_to_string("/etc/hostname"))
        .unwrap_or_default();
    let name: String = raw
        .trim()
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '.' {
                c
            } else {
                '_'
            }
        })
        .collect();
    if name.is_empty() {
        "localhost".into()
    } else {
        name
    }
}

fn now() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

/// An open event file.
#[derive(Debug)]
pub struct EventWriter {
    path: PathBuf,
    file: BufWriter<File>,
    /// Reused encoding buffer (one event at a time).
    buf: Vec<u8>,
}

impl EventWriter {
    /// Create a new event file in `dir` (created if missing) and write the file-version event.
    /// Never overwrites: if the name is taken (same second, host and pid), a counter is added.
    pub fn create(dir: &Path) -> std::io::Result<Self> {
        std::fs::create_dir_all(dir)?;
        let wall = now();
        let base = format!(
            "events.out.tfevents.{}.{}.{}",
            wall as u64,
            hostname(),
            std::process::id()
        );
        let mut n = 0;
        let (path, file) = loop {
            let name = if n == 0 {
                base.clone()
            } else {
                format!("{base}.{n}")
            };
            let path = dir.join(name);
            match File::options().write(true).create_new(true).open(&path) {
                Ok(f) => break (path, f),
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists && n < 1000 => n += 1,
                Err(e) => return Err(e),
            }
        };
        let mut w = Self {
            path,
            file: BufWriter::new(file),
            buf: Vec::with_capacity(512),
        };
        encode_file_version(&mut w.buf, wall, "brain.Event:2");
        w.write_buf()?;
        Ok(w)
    }

    /// The file written.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// One event with every `(tag, value)` at `step`, flushed.
    pub fn add_scalars(&mut self, step: i64, values: &[(&str, f32)]) -> std::io::Result<()> {
        encode_scalars(&mut self.buf, now(), step, values);
        self.write_buf()
    }

    /// Mark a restart at `step` (TensorBoard drops earlier files' points at steps ≥ `step`).
    pub fn session_start(&mut self, step: i64) -> std::io::Result<()> {
        encode_session_start(&mut self.buf, now(), step);
        self.write_buf()
    }

    fn write_buf(&mut self) -> std::io::Result<()> {
        let r = frame_record(&mut self.file, &self.buf).and_then(|_| self.file.flush());
        self.buf.clear();
        r
    }
}

/// Reading event files back: used by the tests here and in `run_dir`, and by anyone who wants
/// the scalars without TensorBoard.
pub mod read {
    use super::crc32c;

    /// One decoded event (only the fields [`super`] writes).
    #[derive(Debug, Clone, PartialEq, Default)]
    pub struct Event {
        /// Seconds since the epoch.
        pub wall_time: f64,
        /// Step.
        pub step: i64,
        /// `file_version`, if set.
        pub file_version: Option<String>,
        /// Summary values (tag, simple_value).
        pub scalars: Vec<(String, f32)>,
        /// `session_log.status`, if set.
        pub session_status: Option<u64>,
    }

    /// Split a TFRecord stream into records, checking both CRCs of each.
    pub fn records(mut bytes: &[u8]) -> Result<Vec<&[u8]>, String> {
        let mut out = Vec::new();
        while !bytes.is_empty() {
            if bytes.len() < 12 {
                return Err(format!("truncated record header ({} bytes)", bytes.len()));
            }
            let (len_bytes, rest) = bytes.split_at(8);
            let len = u64::from_le_bytes(len_bytes.try_into().unwrap()) as usize;
            let len_crc = u32::from_le_bytes(rest[..4].try_into().unwrap());
            if len_crc != crc32c::masked(len_bytes) {
                return Err("length CRC mismatch".into());
            }
            let rest = &rest[4..];
            if rest.len() < len + 4 {
                return Err(format!("truncated record: want {len} + 4 bytes"));
            }
            let (data, rest) = rest.split_at(len);
            let data_crc = u32::from_le_bytes(rest[..4].try_into().unwrap());
            if data_crc != crc32c::masked(data) {
                return Err("data CRC mismatch".into());
            }
            out.push(data);
            bytes = &rest[4..];
        }
        Ok(out)
    }

    struct Fields<'a>(&'a [u8]);

    enum Field<'a> {
        Varint(u64),
        Fixed64([u8; 8]),
        Fixed32([u8; 4]),
        Bytes(&'a [u8]),
    }

    impl<'a> Fields<'a> {
        fn varint(&mut self) -> Result<u64, String> {
            let mut v = 0u64;
            for shift in (0..70).step_by(7) {
                let (&b, rest) = self.0.split_first().ok_or("truncated varint")?;
                self.0 = rest;
                v |= ((b & 0x7f) as u64) << shift;
                if b & 0x80 == 0 {
                    return Ok(v);
                }
            }
            Err("varint too long".into())
        }

        fn take(&mut self, n: usize) -> Result<&'a [u8], String> {
            if self.0.len() < n {
                return Err(format!("truncated field: want {n} bytes"));
            }
            let (a, b) = self.0.split_at(n);
            self.0 = b;
            Ok(a)
        }

        fn next(&mut self) -> Result<Option<(u64, Field<'a>)>, String> {
            if self.0.is_empty() {
                return Ok(None);
            }
            let key = self.varint()?;
            let field = match key & 7 {
                0 => Field::Varint(self.varint()?),
                1 => Field::Fixed64(self.take(8)?.try_into().unwrap()),
                2 => {
                    let n = self.varint()? as usize;
                    Field::Bytes(self.take(n)?)
                }
                5 => Field::Fixed32(self.take(4)?.try_into().unwrap()),
                w => return Err(format!("unsupported wire type {w}")),
            };
            Ok(Some((key >> 3, field)))
        }
    }

    /// Decode one `Event` record.
    pub fn event(data: &[u8]) -> Result<Event, String> {
        let mut e = Event::default();
        let mut f = Fields(data);
        while let Some((num, field)) = f.next()? {
            match (num, field) {
                (1, Field::Fixed64(b)) => e.wall_time = f64::from_le_bytes(b),
                (2, Field::Varint(v)) => e.step = v as i64,
                (3, Field::Bytes(b)) => {
                    e.file_version = Some(String::from_utf8(b.to_vec()).map_err(|e| e.to_string())?)
                }
                (5, Field::Bytes(summary)) => {
                    let mut s = Fields(summary);
                    while let Some((1, Field::Bytes(value))) = s.next()? {
                        let (mut tag, mut val) = (String::new(), f32::NAN);
                        let mut v = Fields(value);
                        while let Some((n, fv)) = v.next()? {
                            match (n, fv) {
                                (1, Field::Bytes(t)) => {
                                    tag =
                                        String::from_utf8(t.to_vec()).map_err(|e| e.to_string())?
                                }
                                (2, Field::Fixed32(x)) => val = f32::from_le_bytes(x),
                                _ => return Err("unexpected field in Summary.Value".into()),
                            }
                        }
                        e.scalars.push((tag, val));
                    }
                }
                (7, Field::Bytes(log)) => {
                    let mut l = Fields(log);
                    while let Some((n, fv)) = l.next()? {
                        if let (1, Field::Varint(s)) = (n, fv) {
                            e.session_status = Some(s);
                        }
                    }
                }
                (n, _) => return Err(format!("unexpected Event field {n}")),
            }
        }
        Ok(e)
    }

    /// Every event of one file.
    pub fn file(path: &std::path::Path) -> Result<Vec<Event>, String> {
        let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
        records(&bytes)?
            .into_iter()
            .map(event)
            .collect::<Result<_, _>>()
            .map_err(|e| format!("{}: {e}", path.display()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc32c_matches_known_vectors() {
        // The standard check value, and the iSCSI test vectors of RFC 3720, appendix B.4.
        assert_eq!(crc32c::checksum(b"123456789"), 0xE306_9283);
        assert_eq!(crc32c::checksum(&[0u8; 32]), 0x8A91_36AA);
        assert_eq!(crc32c::checksum(&[0xffu8; 32]), 0x62A8_AB43);
        let up: Vec<u8> = (0..32).collect();
        assert_eq!(crc32c::checksum(&up), 0x46DD_794E);
        let down: Vec<u8> = (0..32).rev().collect();
        assert_eq!(crc32c::checksum(&down), 0x113F_DB5C);
        assert_eq!(crc32c::checksum(b""), 0);
    }

    #[test]
    fn masking_rotates_right_by_15_and_adds_the_constant() {
        // CRC-32C("123456789") = 0xE3069283; rotated right by 15 = 0x2507c60d (computed
        // separately), plus 0xa282ead8 = 0xc78ab0e5.
        assert_eq!(crc32c::masked(b"123456789"), 0xc78a_b0e5);
    }

    #[test]
    fn scalar_event_has_the_exact_protobuf_bytes() {
        // Event{wall_time=1.5, step=300, summary{value{tag="a/b", simple_value=2.0}}},
        // encoded by hand from event.proto / summary.proto.
        let mut out = Vec::new();
        encode_scalars(&mut out, 1.5, 300, &[("a/b", 2.0)]);
        let mut want = vec![0x09];
        want.extend_from_slice(&1.5f64.to_le_bytes());
        want.extend_from_slice(&[0x10, 0xac, 0x02]); // step 300 as a varint
        want.extend_from_slice(&[0x2a, 12, 0x0a, 10, 0x0a, 3, b'a', b'/', b'b', 0x15]);
        want.extend_from_slice(&2.0f32.to_le_bytes());
        assert_eq!(out, want);
    }

    #[test]
    fn session_start_event_has_the_exact_protobuf_bytes() {
        // Event{wall_time=2.0, step=201, session_log{status=START}}: session_log is field 7.
        let mut out = Vec::new();
        encode_session_start(&mut out, 2.0, 201);
        let mut want = vec![0x09];
        want.extend_from_slice(&2.0f64.to_le_bytes());
        want.extend_from_slice(&[0x10, 0xc9, 0x01, 0x3a, 2, 0x08, 1]);
        assert_eq!(out, want);
    }

    #[test]
    fn reader_parses_what_the_writer_wrote() {
        let dir = std::env::temp_dir().join(format!("mbpo-tb-{}", std::process::id()));
        let mut w = EventWriter::create(&dir).unwrap();
        let long_tag = "x".repeat(200); // lengths ≥ 128 need two-byte varints
        w.add_scalars(100, &[("eval/return", -1234.5), ("sac/alpha", 0.25)])
            .unwrap();
        w.add_scalars(200, &[(long_tag.as_str(), f32::MAX)])
            .unwrap();
        w.session_start(150).unwrap();
        w.add_scalars(-3, &[]).unwrap();
        let name = w.path().file_name().unwrap().to_string_lossy().into_owned();
        assert!(name.starts_with("events.out.tfevents."), "{name}");
        let events = read::file(w.path()).unwrap();
        assert_eq!(events.len(), 5);
        assert_eq!(events[0].file_version.as_deref(), Some("brain.Event:2"));
        assert!(events[0].wall_time > 1.6e9, "{}", events[0].wall_time);
        assert_eq!(events[1].step, 100);
        assert_eq!(
            events[1].scalars,
            vec![("eval/return".into(), -1234.5), ("sac/alpha".into(), 0.25)]
        );
        assert_eq!(events[2].scalars, vec![(long_tag, f32::MAX)]);
        assert_eq!((events[3].step, events[3].session_status), (150, Some(1)));
        assert_eq!((events[4].step, events[4].scalars.len()), (-3, 0));

        // A second writer in the same directory never touches the first file.
        let w2 = EventWriter::create(&dir).unwrap();
        assert_ne!(w2.path(), w.path());
        assert_eq!(read::file(w.path()).unwrap().len(), 5);
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn reader_rejects_corruption() {
        let mut bytes = Vec::new();
        let mut ev = Vec::new();
        encode_scalars(&mut ev, 1.0, 7, &[("t", 1.0)]);
        frame_record(&mut bytes, &ev).unwrap();
        assert_eq!(read::records(&bytes).unwrap(), vec![ev.as_slice()]);
        let mut flipped = bytes.clone();
        flipped[14] ^= 1; // inside the data
        assert!(read::records(&flipped).unwrap_err().contains("data CRC"));
        let mut flipped = bytes.clone();
        flipped[0] ^= 1; // the length
        assert!(read::records(&flipped).unwrap_err().contains("length CRC"));
        assert!(read::records(&bytes[..bytes.len() - 1])
            .unwrap_err()
            .contains("truncated"));
    }
}
