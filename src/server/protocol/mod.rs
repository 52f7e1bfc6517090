//! The WebSocket protocol, version 1.
//!
//! - [`parse_request`] turns one text frame into a [`Request`]: its `id` and its [`Op`], a
//!   serde-tagged enum of the ops, one file each in [`ops`] (the op's struct, its parse and
//!   its `apply`) — or into the error reply's id and a [`ProtocolError`].
//! - [`ok_reply`] and [`error_reply`] build the reply envelope.
//! - [`demods_json`], [`spectrum_json`], [`scope_json`], [`status_json`] and their `_binary`
//!   twins encode data messages; [`decode_header`] reads a binary message's header back.
//!
//! The wire format is pure functions, no sockets and no tasks. An op's `apply` sees only a
//! small context (the control plane, the newest measured values, the client's
//! subscriptions); the session owns the socket and calls it.
//!
//! Everything a client sees is documented in `docs/protocol.md`, the promise this module
//! keeps.

mod data;
mod fields;
mod json;
pub mod ops;
mod reply;
mod request;

use std::fmt;

use crate::config::NodeError;

pub use data::{
    BINARY_HEADER_BYTES, BINARY_MAGIC, BINARY_VERSION, BatchedPoint, BinaryHeader,
    DEMOD_RECORD_BYTES, DemodBatch, POINT_HEADER_BYTES, batched_points, decode_header,
    demods_binary, demods_json, demods_point, force_binary, force_json, image_binary, image_json,
    json_binary, scope_binary, scope_json, spectrum_binary, spectrum_json, status_binary,
    status_json,
};
pub use fields::Fields;
pub use ops::Op;
pub use reply::{error_reply, ok_reply};
pub use request::{Request, parse_request};

/// The protocol version `hello` reports (`protocol`).
pub const PROTOCOL_VERSION: u32 = 1;

/// Largest text frame the server accepts (bytes); larger → close with 1009.
pub const MAX_MESSAGE_BYTES: usize = 64 * 1024;

/// Largest binary frame (a frame of streamed samples) the server accepts (bytes): 4 MiB of
/// samples after the header (2 Mi int16 samples, 0.2 s at 10 MS/s); larger → close with 1009.
pub const MAX_SAMPLE_FRAME_BYTES: usize = 4 * 1024 * 1024 + crate::pipeline::FRAME_HEADER_BYTES;

/// A data stream a client can subscribe to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum StreamKind {
    /// Lock-in outputs, one message per output time point of the bank.
    Demods,
    /// Sliding-FFT magnitudes.
    Spectrum,
    /// Raw photodiode samples (decimated).
    Scope,
    /// Pipeline health and counters.
    Status,
    /// FT-AFM force estimates (τ, F, modulus, waveform).
    Force,
    /// Scan images, one message per finished trace line.
    Image,
    /// Sweeper results, one message per point and a final one.
    Sweep,
    /// The bimodal AM-FM estimate, one message per demodulator frame.
    Bimodal,
    /// Every PID unit update, gathered into one message per pass of the hub.
    Pids,
}

impl StreamKind {
    /// Every stream, in the order of their binary codes.
    pub const ALL: [StreamKind; 9] = [
        StreamKind::Demods,
        StreamKind::Spectrum,
        StreamKind::Scope,
        StreamKind::Status,
        StreamKind::Force,
        StreamKind::Image,
        StreamKind::Sweep,
        StreamKind::Bimodal,
        StreamKind::Pids,
    ];

    /// The name used in requests and in the `stream` field of data messages.
    pub const fn name(self) -> &'static str {
        match self {
            StreamKind::Demods => "demods",
            StreamKind::Spectrum => "spectrum",
            StreamKind::Scope => "scope",
            StreamKind::Status => "status",
            StreamKind::Force => "force",
            StreamKind::Image => "image",
            StreamKind::Sweep => "sweep",
            StreamKind::Bimodal => "bimodal",
            StreamKind::Pids => "pids",
        }
    }

    /// The stream with this name (exact, case-sensitive).
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|s| s.name() == name)
    }

    /// The stable code in byte 6 of the binary header: demods 1, spectrum 2, scope 3,
    /// status 4, force 5, image 6, sweep 7, bimodal 8, pids 9.
    pub const fn code(self) -> u8 {
        match self {
            StreamKind::Demods => 1,
            StreamKind::Spectrum => 2,
            StreamKind::Scope => 3,
            StreamKind::Status => 4,
            StreamKind::Force => 5,
            StreamKind::Image => 6,
            StreamKind::Sweep => 7,
            StreamKind::Bimodal => 8,
            StreamKind::Pids => 9,
        }
    }

    /// The stream with this binary code.
    pub fn from_code(code: u8) -> Option<Self> {
        Self::ALL.into_iter().find(|s| s.code() == code)
    }

    /// `"demods, spectrum, scope, status, force"`, for error messages.
    pub(crate) fn name_list() -> String {
        let names: Vec<&str> = Self::ALL.iter().map(|s| s.name()).collect();
        names.join(", ")
    }
}

impl fmt::Display for StreamKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// How a subscription's data messages are framed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Format {
    /// Text frames with one JSON object each (the default).
    #[default]
    Json,
    /// Binary frames: a 40-byte header and a little-endian payload.
    Binary,
}

impl Format {
    /// Every format.
    pub const ALL: [Format; 2] = [Format::Json, Format::Binary];

    /// `"json"` or `"binary"`.
    pub const fn name(self) -> &'static str {
        match self {
            Format::Json => "json",
            Format::Binary => "binary",
        }
    }

    /// The format with this name (exact, case-sensitive).
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|f| f.name() == name)
    }
}

impl fmt::Display for Format {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// The `error.code` of a failed request.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ErrorCode {
    /// Not JSON, not an object, no `op`, or a field of the wrong type or form.
    BadRequest,
    /// `op` is not one of the protocol's ops.
    UnknownOp,
    /// No node has this path.
    UnknownPath,
    /// The node cannot be set at runtime.
    ReadOnly,
    /// The node refuses the value (type, range, relation with other nodes).
    InvalidValue,
    /// No stream has this name.
    UnknownStream,
    /// The client sends requests faster than the server's limit.
    RateLimited,
    /// The server cannot do it now (e.g. a settings change is in progress); retry.
    Busy,
    /// A measured value was asked for that does not exist now (e.g. the latest output of
    /// a disabled demodulator).
    NoData,
    /// A bug or an unexpected failure in the server.
    Internal,
}

impl ErrorCode {
    /// Every code.
    pub const ALL: [ErrorCode; 10] = [
        ErrorCode::BadRequest,
        ErrorCode::UnknownOp,
        ErrorCode::UnknownPath,
        ErrorCode::ReadOnly,
        ErrorCode::InvalidValue,
        ErrorCode::UnknownStream,
        ErrorCode::RateLimited,
        ErrorCode::Busy,
        ErrorCode::NoData,
        ErrorCode::Internal,
    ];

    /// The code as it appears on the wire, e.g. `"bad_request"`.
    pub const fn as_str(self) -> &'static str {
        match self {
            ErrorCode::BadRequest => "bad_request",
            ErrorCode::UnknownOp => "unknown_op",
            ErrorCode::UnknownPath => "unknown_path",
            ErrorCode::ReadOnly => "read_only",
            ErrorCode::InvalidValue => "invalid_value",
            ErrorCode::UnknownStream => "unknown_stream",
            ErrorCode::RateLimited => "rate_limited",
            ErrorCode::Busy => "busy",
            ErrorCode::NoData => "no_data",
            ErrorCode::Internal => "internal",
        }
    }

    /// The code with this wire name.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|c| c.as_str() == name)
    }
}

impl fmt::Display for ErrorCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A failed request: the code and a sentence naming the field, what was given and what is
/// allowed.
#[derive(Clone, Debug, PartialEq)]
pub struct ProtocolError {
    /// What kind of failure.
    pub code: ErrorCode,
    /// The human-readable sentence.
    pub message: String,
}

impl ProtocolError {
    /// An error with this code and message.
    pub fn new(code: ErrorCode, message: impl Into<String>) -> Self {
        Self {
            code,
            message: message.into(),
        }
    }
}

impl fmt::Display for ProtocolError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.code, self.message)
    }
}

impl std::error::Error for ProtocolError {}

impl From<&NodeError> for ProtocolError {
    /// Maps by [`NodeError::code`] (a code this protocol does not know becomes `internal`);
    /// the message is the error's `Display`.
    fn from(error: &NodeError) -> Self {
        let code = ErrorCode::from_name(error.code()).unwrap_or(ErrorCode::Internal);
        Self::new(code, error.to_string())
    }
}

impl From<NodeError> for ProtocolError {
    fn from(error: NodeError) -> Self {
        Self::from(&error)
    }
}

impl From<crate::instrument::ChangeError> for ProtocolError {
    fn from(error: crate::instrument::ChangeError) -> Self {
        use crate::instrument::ChangeError;
        match error {
            ChangeError::Node(e) => Self::from(&e),
            ChangeError::Busy(m) => Self::new(ErrorCode::Busy, m),
            ChangeError::ReadOnly(m) => Self::new(ErrorCode::ReadOnly, m),
            ChangeError::Declined(m) => Self::new(ErrorCode::InvalidValue, m),
            ChangeError::Internal(m) => Self::new(ErrorCode::Internal, m),
        }
    }
}
