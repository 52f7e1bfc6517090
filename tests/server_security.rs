//! What a hostile page or a careless client cannot do: reach the daemon through DNS
//! rebinding (a Host that is not this server's), send two Origins, frame the dashboard, or
//! grow the daemon's memory by not reading large messages.

use serde_json::json;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;

mod common;
use common::*;

/// One raw HTTP/1.1 request with the given header lines; returns (status, head, body).
async fn raw(addr: std::net::SocketAddr, path: &str, headers: &str) -> (u16, String, String) {
    let mut s = TcpStream::connect(addr).await.unwrap();
    s.write_all(format!("GET {path} HTTP/1.1\r\n{headers}Connection: close\r\n\r\n").as_bytes())
        .await
        .unwrap();
    let mut bytes = Vec::new();
    s.read_to_end(&mut bytes).await.unwrap();
    let text = String::from_utf8_lossy(&bytes).into_owned();
    let status = text[9..12].parse().unwrap();
    let (head, body) = text.split_once("\r\n\r\n").unwrap_or((&text, ""));
    (status, head.to_ascii_lowercase(), body.to_owned())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn only_names_of_this_server_reach_it() {
    let d = Daemon::start(light()).await;
    let port = d.addr.port();
    // A rebinding page's requests name its own host: refused, for pages, metrics and the
    // WebSocket alike, with a message that names the node to add it to.
    for path in ["/", "/metrics", "/app.js"] {
        let (status, _, body) = raw(d.addr, path, "Host: evil.example\r\n").await;
        assert_eq!(status, 403, "{path}");
        assert!(body.contains("/server/allowed_hosts"), "{body}");
    }
    let mut request = format!("ws://{}/ws", d.addr).into_client_request().unwrap();
    request
        .headers_mut()
        .insert("Host", format!("evil.example:{port}").parse().unwrap());
    request.headers_mut().insert(
        "Origin",
        format!("http://evil.example:{port}").parse().unwrap(),
    );
    assert!(
        tokio_tungstenite::connect_async(request).await.is_err(),
        "a rebinding page opened the WebSocket"
    );
    // IP literals and loopback names pass.
    for host in [
        format!("127.0.0.1:{port}"),
        format!("localhost:{port}"),
        format!("[::1]:{port}"),
        "ftafm.localhost".to_owned(),
    ] {
        let (status, _, _) = raw(d.addr, "/", &format!("Host: {host}\r\n")).await;
        assert_eq!(status, 200, "{host}");
    }
    // No Host at all: 400. Health probes may use any name.
    let (status, _, _) = raw(d.addr, "/", "").await;
    assert_eq!(status, 400);
    let (status, _, _) = raw(d.addr, "/healthz", "Host: probe.internal\r\n").await;
    assert_ne!(status, 403);
    // A name the operator lists is let in, at once.
    let mut ws = connect(d.addr).await;
    let r = call(
        &mut ws,
        json!({"id": 1, "op": "set", "path": "/server/allowed_hosts", "value": ["lab-pc.example.org"]}),
    )
    .await;
    assert_eq!(r["ok"], true, "{r}");
    let (status, _, _) = raw(d.addr, "/", "Host: lab-pc.example.org:8700\r\n").await;
    assert_eq!(status, 200);
    let r = call(
        &mut ws,
        json!({"id": 2, "op": "set", "path": "/server/allowed_hosts", "value": ["*.example.org"]}),
    )
    .await;
    assert_eq!(code(&r), "invalid_value", "{r}");
    let (_, metrics) = http_get(d.addr, "/metrics").await;
    assert!(
        metrics.contains("ftafm_http_requests_refused_total "),
        "{metrics}"
    );
    d.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_origins_are_refused_and_pages_cannot_be_framed() {
    let d = Daemon::start(light()).await;
    let host = format!("Host: {}\r\n", d.addr);
    let own = format!("http://{}", d.addr);
    let (status, _, _) = raw(
        d.addr,
        "/ws",
        &format!(
            "{host}Upgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Version: 13\r\n\
             Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nOrigin: {own}\r\nOrigin: http://evil.example\r\n"
        ),
    )
    .await;
    assert_eq!(status, 403);
    for path in ["/", "/app.js", "/metrics"] {
        let (status, head, _) = raw(d.addr, path, &host).await;
        assert_eq!(status, 200, "{path}");
        assert!(
            head.contains("x-content-type-options: nosniff"),
            "{path}: {head}"
        );
        assert!(head.contains("x-frame-options: deny"), "{path}: {head}");
        assert!(
            head.contains("content-security-policy: default-src 'self'")
                && head.contains("frame-ancestors 'none'"),
            "{path}: {head}"
        );
    }
    d.shutdown().await;
}
