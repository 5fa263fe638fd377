//! In a worker, an openpi policy's `api_key_env` names only a variable its operator allowed: the
//! policy string is a submitter's, and so is the URL the key would go to. A test binary of its
//! own: the allowed variables are the process's, set once, as a worker sets them.

mod common;

use std::net::TcpListener;
use std::sync::mpsc;
use std::time::Duration;

use assay_model::policy::{Interface, PolicyError};
use assay_policy::openpi::{OpenPiPolicy, allow_key_vars};

/// A server that takes one connection, reports its Authorization header, sends openpi's
/// metadata and closes.
fn server() -> (String, mpsc::Receiver<Option<String>>) {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let url = format!("ws://{}", listener.local_addr().unwrap());
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for stream in listener.incoming() {
            let Ok(stream) = stream else { return };
            let (mut ws, auth) = common::accept_with_auth(stream);
            let mut metadata = Vec::new();
            rmpv::encode::write_value(&mut metadata, &rmpv::Value::Map(Vec::new())).unwrap();
            ws.send(tungstenite::Message::Binary(metadata.into()))
                .unwrap();
            let _ = tx.send(auth);
        }
    });
    (url, rx)
}

#[test]
fn a_worker_sends_only_the_keys_its_operator_allowed() {
    // Cargo's own variables stand for a worker's key and one of its secrets.
    let (allowed_var, secret_var) = ("CARGO_PKG_NAME", "CARGO_MANIFEST_DIR");
    allow_key_vars(&[allowed_var.to_owned()]).unwrap();
    // The same list again is harmless; another is refused.
    allow_key_vars(&[allowed_var.to_owned()]).unwrap();
    assert!(allow_key_vars(&[secret_var.to_owned()]).is_err());

    let (url, seen) = server();
    // Another variable of the worker's environment: refused before anything is sent or read.
    let err = OpenPiPolicy::new(
        &url,
        Duration::from_secs(5),
        Some(secret_var),
        Interface::default(),
    )
    .unwrap_err();
    let PolicyError::Load(msg) = &err else {
        panic!("expected a load error, got {err:?}")
    };
    assert!(
        msg.contains(&format!("api_key_env={secret_var}"))
            && msg.contains("not one of the variables")
            && msg.contains(allowed_var),
        "{msg}"
    );
    let value = std::env::var(secret_var).unwrap();
    assert!(
        !msg.contains(&value),
        "the error shows the variable's value: {msg}"
    );
    assert!(
        seen.recv_timeout(Duration::from_millis(300)).is_err(),
        "the worker connected to the submitter's server"
    );

    // The allowed one goes in openpi's header.
    OpenPiPolicy::new(
        &url,
        Duration::from_secs(5),
        Some(allowed_var),
        Interface::default(),
    )
    .unwrap();
    let auth = seen.recv_timeout(Duration::from_secs(5)).unwrap();
    assert_eq!(
        auth,
        Some(format!("Api-Key {}", std::env::var(allowed_var).unwrap()))
    );
}
