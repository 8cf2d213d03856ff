//! HTTP/1.1 exchanges written by hand, for what a client library would not send: a body that
//! stops, a length that lies, chunks.

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::time::Duration;

/// A bare HTTP/1.1 GET: (status, body), or `None` if the connection failed.
pub fn raw_get(addr: SocketAddr, path: &str) -> Option<(u16, String)> {
    let mut s = TcpStream::connect_timeout(&addr, Duration::from_secs(1)).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(5))).ok()?;
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n"
    )
    .ok()?;
    let mut text = String::new();
    s.read_to_string(&mut text).ok()?;
    let (status, body) = parse_answer(&text);
    (status != 0).then_some((status, body))
}

/// The status and body of an HTTP/1.1 answer read whole (status 0 when there is none).
pub fn parse_answer(text: &str) -> (u16, String) {
    let status = text
        .split_whitespace()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(0);
    let body = text.split("\r\n\r\n").nth(1).unwrap_or("").to_string();
    (status, body)
}

/// A bare HTTP/1.1 POST with the given content type and body bytes: (status, body).
pub fn raw_post(addr: SocketAddr, path: &str, content_type: &str, body: &[u8]) -> (u16, String) {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    write!(
        s,
        "POST {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\nContent-Type: {content_type}\r\nContent-Length: {}\r\n\r\n",
        body.len()
    )
    .unwrap();
    s.write_all(body).unwrap();
    let mut text = String::new();
    s.read_to_string(&mut text).unwrap();
    parse_answer(&text)
}

/// The head of an HTTP/1.1 JSON POST declaring `length` body bytes (plus `extra` header lines),
/// without the body: (status, body) of the answer.
pub fn raw_head_only_post(addr: SocketAddr, path: &str, length: u64, extra: &str) -> (u16, String) {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    write!(
        s,
        "POST {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\nContent-Type: application/json\r\nContent-Length: {length}\r\n{extra}\r\n"
    )
    .unwrap();
    let mut text = String::new();
    let _ = s.read_to_string(&mut text);
    parse_answer(&text)
}

/// A chunked HTTP/1.1 POST of JSON whose length is not declared: (status, body).
pub fn raw_chunked_post(addr: SocketAddr, path: &str, chunks: &[&[u8]]) -> (u16, String) {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    write!(
        s,
        "POST {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\nContent-Type: application/json\r\nTransfer-Encoding: chunked\r\n\r\n"
    )
    .unwrap();
    for c in chunks {
        // The server may answer and close before the whole body is sent.
        if write!(s, "{:x}\r\n", c.len()).is_err() || s.write_all(c).is_err() {
            break;
        }
        let _ = s.write_all(b"\r\n");
    }
    let _ = s.write_all(b"0\r\n\r\n");
    let mut text = String::new();
    let _ = s.read_to_string(&mut text);
    parse_answer(&text)
}
