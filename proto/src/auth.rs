//! The cluster token: a shared secret every gRPC call to the coordinator carries
//! (`authorization: Bearer <token>`), from clients and workers alike.
//!
//! The token is read from `$ASSAY_CLUSTER_TOKEN`, or from the file `$ASSAY_CLUSTER_TOKEN_FILE`
//! names (a mounted Kubernetes Secret). It is never a command-line flag (flags show in `ps`),
//! never printed: [`Token`]'s `Debug` and `Display` redact it. A coordinator started with a token
//! refuses every call without it, with `UNAUTHENTICATED`; one started without a token accepts
//! every call (a laptop, loopback only).

use std::sync::Arc;

use tonic::metadata::{Ascii, MetadataValue};
use tonic::service::Interceptor;
use tonic::{Request, Status};

pub const TOKEN_ENV: &str = "ASSAY_CLUSTER_TOKEN";
pub const TOKEN_FILE_ENV: &str = "ASSAY_CLUSTER_TOKEN_FILE";

/// Shortest token accepted: 16 characters (a guessable token is no protection).
pub const MIN_TOKEN_LEN: usize = 16;

/// A cluster token. Its `Debug` and `Display` never show it.
#[derive(Clone, PartialEq, Eq)]
pub struct Token(Arc<str>);

impl std::fmt::Debug for Token {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Token(<redacted>)")
    }
}

impl std::fmt::Display for Token {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("<redacted>")
    }
}

impl Token {
    /// A token from its text (surrounding whitespace dropped): at least [`MIN_TOKEN_LEN`]
    /// printable ASCII characters, no spaces.
    pub fn new(text: &str) -> Result<Self, String> {
        let t = text.trim();
        if t.len() < MIN_TOKEN_LEN {
            return Err(format!(
                "the cluster token has {} characters; it needs at least {MIN_TOKEN_LEN}",
                t.len()
            ));
        }
        if !t.bytes().all(|b| b.is_ascii_graphic()) {
            return Err("the cluster token must be printable ASCII without spaces".into());
        }
        Ok(Self(t.into()))
    }

    /// The token from `$ASSAY_CLUSTER_TOKEN` or the file `$ASSAY_CLUSTER_TOKEN_FILE`; `None`
    /// when neither is set. An unreadable file or a malformed token is an error (a cluster
    /// meant to be protected must not start open).
    pub fn from_env() -> Result<Option<Self>, String> {
        if let Some(v) = std::env::var_os(TOKEN_ENV) {
            let v = v
                .into_string()
                .map_err(|_| format!("${TOKEN_ENV} is not UTF-8"))?;
            return Self::new(&v)
                .map(Some)
                .map_err(|e| format!("${TOKEN_ENV}: {e}"));
        }
        if let Some(path) = std::env::var_os(TOKEN_FILE_ENV) {
            let text = std::fs::read_to_string(&path).map_err(|e| {
                format!(
                    "${TOKEN_FILE_ENV} names {}, which cannot be read: {e}",
                    std::path::Path::new(&path).display()
                )
            })?;
            return Self::new(&text)
                .map(Some)
                .map_err(|e| format!("{}: {e}", std::path::Path::new(&path).display()));
        }
        Ok(None)
    }

    /// A secret for another part of the cluster, derived from the token: hex SHA-256 of
    /// `assay/<purpose>`, a NUL and the token. Telemetry's zenoh password is `derive("zenoh")`,
    /// so the token itself never leaves the gRPC headers, and one secret does not give away
    /// another.
    pub fn derive(&self, purpose: &str) -> String {
        use sha2::Digest;
        let mut h = sha2::Sha256::new();
        h.update(b"assay/");
        h.update(purpose.as_bytes());
        h.update([0u8]);
        h.update(self.0.as_bytes());
        hex::encode(h.finalize())
    }

    /// The token for another service of the cluster: [`Token::derive`] of `purpose`, as a token.
    /// Policy servers get `for_service("policy")`: a policy server that leaks what it is sent
    /// gives away neither the coordinator's token nor another service's.
    pub fn for_service(&self, purpose: &str) -> Token {
        Token(self.derive(purpose).into())
    }

    fn header(&self) -> MetadataValue<Ascii> {
        format!("Bearer {}", self.0)
            .parse()
            .expect("a token is printable ASCII")
    }

    /// Whether `presented` is this token, in time independent of where they differ.
    fn matches(&self, presented: &str) -> bool {
        let (a, b) = (self.0.as_bytes(), presented.as_bytes());
        let mut diff = a.len() ^ b.len();
        for (i, x) in a.iter().enumerate() {
            diff |= usize::from(x ^ b.get(i).copied().unwrap_or(0));
        }
        diff == 0
    }
}

/// Client side: adds the token to every request (nothing when there is none).
#[derive(Clone, Debug, Default)]
pub struct AttachToken(Option<Token>);

impl AttachToken {
    pub fn new(token: Option<Token>) -> Self {
        Self(token)
    }
}

impl Interceptor for AttachToken {
    fn call(&mut self, mut req: Request<()>) -> Result<Request<()>, Status> {
        if let Some(t) = &self.0 {
            req.metadata_mut().insert("authorization", t.header());
        }
        Ok(req)
    }
}

/// Server side: refuses every request that does not carry the token (all pass when there is
/// none).
#[derive(Clone, Debug, Default)]
pub struct RequireToken(Option<Token>);

impl RequireToken {
    pub fn new(token: Option<Token>) -> Self {
        Self(token)
    }
}

impl Interceptor for RequireToken {
    fn call(&mut self, req: Request<()>) -> Result<Request<()>, Status> {
        let Some(token) = &self.0 else {
            return Ok(req);
        };
        let presented = req
            .metadata()
            .get("authorization")
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.strip_prefix("Bearer "));
        match presented {
            Some(p) if token.matches(p) => Ok(req),
            Some(_) => Err(Status::unauthenticated(
                "wrong cluster token (set ASSAY_CLUSTER_TOKEN or ASSAY_CLUSTER_TOKEN_FILE to the cluster's)",
            )),
            None => Err(Status::unauthenticated(
                "this coordinator requires the cluster token (set ASSAY_CLUSTER_TOKEN or ASSAY_CLUSTER_TOKEN_FILE)",
            )),
        }
    }
}

/// A channel that carries the token.
pub type Channel =
    tonic::service::interceptor::InterceptedService<tonic::transport::Channel, AttachToken>;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tokens_are_checked_and_never_shown() {
        let t = Token::new("  0123456789abcdef-secret\n").unwrap();
        assert_eq!(format!("{t:?} {t}"), "Token(<redacted>) <redacted>");
        assert!(Token::new("short").unwrap_err().contains("at least 16"));
        assert!(Token::new("has a space in it!!").is_err());
        let mut client = AttachToken::new(Some(t.clone()));
        let req = client.call(Request::new(())).unwrap();
        let mut server = RequireToken::new(Some(t.clone()));
        assert!(server.call(req).is_ok());
        let err = server.call(Request::new(())).unwrap_err();
        assert_eq!(err.code(), tonic::Code::Unauthenticated);
        let mut wrong = AttachToken::new(Some(Token::new("0123456789abcdef-secreT").unwrap()));
        let err = server
            .call(wrong.call(Request::new(())).unwrap())
            .unwrap_err();
        assert!(err.message().contains("wrong cluster token"));
        assert!(!err.message().contains("secret"));
        // A prefix or an extension of the token is not the token.
        assert!(!t.matches("0123456789abcdef-secre"));
        assert!(!t.matches("0123456789abcdef-secrett"));
        assert!(RequireToken::new(None).call(Request::new(())).is_ok());
        // Derived secrets: fixed per token and purpose, different across them, never the token.
        let z = t.derive("zenoh");
        assert_eq!(z, t.derive("zenoh"));
        assert_eq!(z.len(), 64);
        assert_ne!(z, t.derive("policy"));
        assert_ne!(
            z,
            Token::new("0123456789abcdef-secreT")
                .unwrap()
                .derive("zenoh")
        );
        assert!(!z.contains("secret"));
        // The documented recipe (docs/policies.md), computed with Python's hashlib.
        assert_eq!(
            t.derive("policy"),
            "bcc6bfc2549c45f3ff6350548aa61093f4bd01d5a8c67362f2f0499f46011b7e"
        );
        let p = t.for_service("policy");
        assert!(p.matches(&t.derive("policy")) && !p.matches("0123456789abcdef-secret"));
    }
}
