//! A small JSON writer over a `Vec<u8>`: numbers through serde_json's formatter (shortest
//! round-trip floats, non-finite floats as `null`), strings escaped by serde_json. No
//! per-value allocation.

use serde::Serialize;
use serde_json::ser::{CompactFormatter, Formatter};

/// Writing into a `Vec<u8>` cannot fail; serde_json's API returns `io::Result` anyway.
const VEC_WRITE: &str = "writing JSON into a Vec<u8> cannot fail";

pub(super) struct JsonBuf {
    buf: Vec<u8>,
}

impl JsonBuf {
    pub(super) fn with_capacity(capacity: usize) -> Self {
        Self {
            buf: Vec::with_capacity(capacity),
        }
    }

    /// Appends JSON text as is (the caller guarantees it is valid in place).
    #[inline]
    pub(super) fn raw(&mut self, text: &str) {
        self.buf.extend_from_slice(text.as_bytes());
    }

    /// Appends a quoted, escaped string.
    #[inline]
    pub(super) fn string(&mut self, text: &str) {
        serde_json::to_writer(&mut self.buf, text).expect(VEC_WRITE);
    }

    /// Appends a number, or `null` when it is NaN or infinite.
    #[inline]
    pub(super) fn f64(&mut self, value: f64) {
        if value.is_finite() {
            CompactFormatter
                .write_f64(&mut self.buf, value)
                .expect(VEC_WRITE);
        } else {
            self.raw("null");
        }
    }

    /// Appends a number in f32's shortest form, or `null` when it is NaN or infinite.
    #[inline]
    pub(super) fn f32(&mut self, value: f32) {
        if value.is_finite() {
            CompactFormatter
                .write_f32(&mut self.buf, value)
                .expect(VEC_WRITE);
        } else {
            self.raw("null");
        }
    }

    #[inline]
    pub(super) fn u64(&mut self, value: u64) {
        CompactFormatter
            .write_u64(&mut self.buf, value)
            .expect(VEC_WRITE);
    }

    /// Appends `value` serialised by serde_json (floats that are not finite become `null`).
    pub(super) fn serialize<T: Serialize + ?Sized>(&mut self, value: &T) {
        serde_json::to_writer(&mut self.buf, value)
            .expect("serialising a JSON value or a plain struct into a Vec<u8> cannot fail");
    }

    /// Bytes written so far.
    pub(super) fn len(&self) -> usize {
        self.buf.len()
    }

    /// The bytes from `start` on.
    pub(super) fn tail(&self, start: usize) -> &[u8] {
        &self.buf[start..]
    }

    /// Drops everything from `len` on.
    pub(super) fn truncate(&mut self, len: usize) {
        self.buf.truncate(len);
    }

    /// Overwrites the byte at `index` with an ASCII byte.
    pub(super) fn set_ascii(&mut self, index: usize, byte: u8) {
        debug_assert!(byte.is_ascii() && self.buf[index].is_ascii());
        self.buf[index] = byte;
    }

    pub(super) fn into_string(self) -> String {
        String::from_utf8(self.buf).expect("serde_json writes UTF-8 and raw text is &str")
    }
}
