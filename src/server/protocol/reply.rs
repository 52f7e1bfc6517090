//! The reply envelope.

use serde_json::{Map, Value};

use super::ProtocolError;
use super::json::JsonBuf;

/// `{"id":…,"ok":true,…fields}`, `id` and `ok` first, then `fields` in the map's order.
///
/// `fields` must not contain `"id"` or `"ok"`: the envelope's own keys win and such entries
/// are left out.
pub fn ok_reply(id: &Value, fields: Map<String, Value>) -> String {
    let mut out = JsonBuf::with_capacity(64);
    out.raw("{\"id\":");
    out.serialize(id);
    out.raw(",\"ok\":true");
    for (key, value) in &fields {
        if key == "id" || key == "ok" {
            continue;
        }
        out.raw(",");
        out.string(key);
        out.raw(":");
        out.serialize(value);
    }
    out.raw("}");
    out.into_string()
}

/// `{"id":…,"ok":false,"error":{"code":…,"message":…}}`.
pub fn error_reply(id: &Value, error: &ProtocolError) -> String {
    let mut out = JsonBuf::with_capacity(96 + error.message.len());
    out.raw("{\"id\":");
    out.serialize(id);
    out.raw(",\"ok\":false,\"error\":{\"code\":");
    out.string(error.code.as_str());
    out.raw(",\"message\":");
    out.string(&error.message);
    out.raw("}}");
    out.into_string()
}
