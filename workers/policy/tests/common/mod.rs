//! What the policy tests' stand-in openpi servers share.

use std::net::TcpStream;

/// Accepts a WebSocket handshake on `stream`, keeping the Authorization header the client sent.
// tungstenite's handshake callback has its HTTP response as the error type: not ours to shrink.
#[allow(clippy::result_large_err)]
pub fn accept_with_auth(stream: TcpStream) -> (tungstenite::WebSocket<TcpStream>, Option<String>) {
    let mut auth = None;
    let ws = tungstenite::accept_hdr(
        stream,
        |req: &tungstenite::handshake::server::Request, resp| {
            auth = req
                .headers()
                .get("authorization")
                .map(|h| h.to_str().unwrap().to_owned());
            Ok(resp)
        },
    )
    .unwrap();
    (ws, auth)
}
