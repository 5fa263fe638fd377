//! Credentials: who may call the coordinator, and for what.
//!
//! Every gRPC call to the coordinator carries one credential (`authorization: Bearer <key>`).
//! There are four, by what they may do ([`Access`]):
//!
//! - the **cluster token** (`$ASSAY_CLUSTER_TOKEN`, or the file `$ASSAY_CLUSTER_TOKEN_FILE`
//!   names): the admin credential, good for everything, as before roles existed;
//! - a **worker key** (`$ASSAY_WORKER_TOKEN[_FILE]`): registers a worker (`WorkerSession`) and
//!   nothing else: it cannot submit, cancel or read status and reports;
//! - a **submitter key** (`$ASSAY_SUBMITTER_TOKEN[_FILE]`): submits and cancels batches, and
//!   reads what a viewer reads; it cannot register a worker;
//! - a **viewer key** (`$ASSAY_VIEWER_TOKEN[_FILE]`): reads status and reports, nothing else.
//!
//! A role's key is, by default, derived from the cluster token ([`Token::role_key`]: hex SHA-256
//! of `assay/role/<role>`, a NUL and the token; `assay token derive --role worker` prints it), so
//! an operator with the one token hands out role keys and the coordinator needs nothing more.
//! A coordinator given a role's key itself (`$ASSAY_WORKER_TOKEN_FILE`, …) accepts that key for
//! the role instead of the derived one, so one role's key can be rotated alone. Which RPC takes
//! which role is the coordinator's table (`assay_coordinator::access`).
//!
//! The coordinator holds its credentials in a [`Keyring`] that re-reads the `_FILE` variants
//! ([`Keyring::reload`], every few seconds): a rotated Kubernetes Secret, which kubelet swaps
//! in place, is accepted — and the old key refused — without a restart.
//!
//! Other services keep their own secrets, derived from the cluster token so the token never
//! leaves the coordinator's gRPC headers: policy servers check [`Token::for_service`]`("policy")`,
//! world-model servers `("world-model")`. A process without the cluster token (a worker holding
//! only its worker key) reads such a secret from `$ASSAY_POLICY_TOKEN[_FILE]`, … instead
//! ([`Token::service_from_env`]; `assay token derive --service policy` prints it). Telemetry's
//! zenoh router admits every credential's holder under its own user name ([`Credential::zenoh_login`]).
//!
//! Never a command-line flag (flags show in `ps`), never printed: [`Token`]'s `Debug` and
//! `Display` redact it. A coordinator with no credential at all accepts every call (a laptop,
//! loopback only); one with any refuses a call without one with `UNAUTHENTICATED`, and a call
//! its credential's role may not make with `PERMISSION_DENIED`.

use std::path::{Path, PathBuf};
use std::sync::{Arc, RwLock};

use tonic::metadata::{Ascii, MetadataValue};
use tonic::service::Interceptor;
use tonic::{Request, Status};

pub const TOKEN_ENV: &str = "ASSAY_CLUSTER_TOKEN";
pub const TOKEN_FILE_ENV: &str = "ASSAY_CLUSTER_TOKEN_FILE";

/// Shortest token accepted: 16 characters (a guessable token is no protection).
pub const MIN_TOKEN_LEN: usize = 16;

/// What a credential may do. `Admin` is the cluster token; the others are role keys.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Access {
    Admin,
    Worker,
    Submitter,
    Viewer,
}

impl Access {
    /// The three roles a key can be made for (every access but `Admin`).
    pub const ROLES: [Access; 3] = [Access::Worker, Access::Submitter, Access::Viewer];

    /// The lowercase name used on the command line, in messages and as zenoh user name.
    pub fn name(self) -> &'static str {
        match self {
            Access::Admin => "admin",
            Access::Worker => "worker",
            Access::Submitter => "submitter",
            Access::Viewer => "viewer",
        }
    }

    /// A role by its name (`worker`, `submitter`, `viewer`); the admin is no role.
    pub fn parse_role(s: &str) -> Option<Access> {
        Self::ROLES.into_iter().find(|r| r.name() == s)
    }

    /// The variable holding this credential, and the one naming a file that holds it.
    pub fn env(self) -> (&'static str, &'static str) {
        match self {
            Access::Admin => (TOKEN_ENV, TOKEN_FILE_ENV),
            Access::Worker => ("ASSAY_WORKER_TOKEN", "ASSAY_WORKER_TOKEN_FILE"),
            Access::Submitter => ("ASSAY_SUBMITTER_TOKEN", "ASSAY_SUBMITTER_TOKEN_FILE"),
            Access::Viewer => ("ASSAY_VIEWER_TOKEN", "ASSAY_VIEWER_TOKEN_FILE"),
        }
    }

    /// What this credential is called in messages: "the cluster token", "a worker key".
    pub fn credential(self) -> String {
        match self {
            Access::Admin => "the cluster token".into(),
            role => format!("a {} key", role.name()),
        }
    }

    /// The zenoh user name its holders present to the telemetry router: `assay` for the
    /// cluster token (as before roles), the role's name for a role key.
    pub fn zenoh_user(self) -> &'static str {
        match self {
            Access::Admin => "assay",
            role => role.name(),
        }
    }
}

/// A cluster token, role key or service secret. Its `Debug` and `Display` never show it.
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
                "the token has {} characters; it needs at least {MIN_TOKEN_LEN}",
                t.len()
            ));
        }
        if !t.bytes().all(|b| b.is_ascii_graphic()) {
            return Err("the token must be printable ASCII without spaces".into());
        }
        Ok(Self(t.into()))
    }

    /// The cluster token from `$ASSAY_CLUSTER_TOKEN` or the file `$ASSAY_CLUSTER_TOKEN_FILE`;
    /// `None` when neither is set. An unreadable file or a malformed token is an error (a
    /// cluster meant to be protected must not start open).
    pub fn from_env() -> Result<Option<Self>, String> {
        read_env(TOKEN_ENV, TOKEN_FILE_ENV)
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

    /// The key of `access` derived from this cluster token: `for_service("role/<role>")`
    /// (the admin's is the token itself). What `assay token derive --role <role>` prints.
    pub fn role_key(&self, access: Access) -> Token {
        match access {
            Access::Admin => self.clone(),
            role => self.for_service(&format!("role/{}", role.name())),
        }
    }

    /// The secret a `purpose` server checks (`policy`, `world-model`): `$ASSAY_<PURPOSE>_TOKEN`
    /// or the file `$ASSAY_<PURPOSE>_TOKEN_FILE` names (`-` read as `_`), else
    /// [`Token::for_service`] of the cluster token; `None` when there is neither. A worker that
    /// holds only its worker key gets the policy servers' secret this way.
    pub fn service_from_env(purpose: &str) -> Result<Option<Token>, String> {
        let var = format!("ASSAY_{}_TOKEN", purpose.to_uppercase().replace('-', "_"));
        if let Some(t) = read_env(&var, &format!("{var}_FILE"))? {
            return Ok(Some(t));
        }
        Ok(Self::from_env()?.map(|t| t.for_service(purpose)))
    }

    /// The secret itself, for the one place that must print it: `assay token derive`, which
    /// hands a derived key to an operator. Never log it.
    pub fn expose(&self) -> &str {
        &self.0
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

/// The token in `$var`, or in the file `$file_var` names; `None` when neither is set.
fn read_env(var: &str, file_var: &str) -> Result<Option<Token>, String> {
    if let Some(v) = std::env::var_os(var) {
        let v = v
            .into_string()
            .map_err(|_| format!("${var} is not UTF-8"))?;
        return Token::new(&v).map(Some).map_err(|e| format!("${var}: {e}"));
    }
    if let Some(path) = std::env::var_os(file_var) {
        return read_file(Path::new(&path))
            .map(Some)
            .map_err(|e| format!("${file_var} names {e}"));
    }
    Ok(None)
}

fn read_file(path: &Path) -> Result<Token, String> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| format!("{}, which cannot be read: {e}", path.display()))?;
    Token::new(&text).map_err(|e| format!("{}: {e}", path.display()))
}

/// The credential a client process presents, and what it is.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Credential {
    pub access: Access,
    pub token: Token,
}

impl Credential {
    /// The cluster token when this process has one, else the key of the first of `roles` it
    /// has (`$ASSAY_WORKER_TOKEN[_FILE]`, …); `None` when it has none. A worker asks for
    /// `[Worker]`; `assay submit`, `status` and `report` for `[Submitter, Viewer]`; `assay top`
    /// for any role.
    pub fn from_env(roles: &[Access]) -> Result<Option<Credential>, String> {
        for access in std::iter::once(Access::Admin).chain(roles.iter().copied()) {
            let (var, file_var) = access.env();
            if let Some(token) = read_env(var, file_var)? {
                return Ok(Some(Credential { access, token }));
            }
        }
        Ok(None)
    }

    /// The token of [`Credential::from_env`], for a channel.
    pub fn token_from_env(roles: &[Access]) -> Result<Option<Token>, String> {
        Ok(Self::from_env(roles)?.map(|c| c.token))
    }

    /// The user name and password its holder presents to the telemetry router: the access's
    /// zenoh user, and [`Token::derive`]`("zenoh")` of its token.
    pub fn zenoh_login(&self) -> (&'static str, String) {
        (self.access.zenoh_user(), self.token.derive("zenoh"))
    }
}

/// Where the coordinator reads one credential: a variable's value (fixed), or a file it
/// re-reads (a mounted Secret, rotated in place).
#[derive(Clone)]
enum Source {
    Fixed(Token),
    File { var: &'static str, path: PathBuf },
}

impl Source {
    fn from_env(access: Access) -> Result<Option<Source>, String> {
        let (var, file_var) = access.env();
        if std::env::var_os(var).is_some() {
            return Ok(read_env(var, file_var)?.map(Source::Fixed));
        }
        match std::env::var_os(file_var) {
            Some(path) => {
                let source = Source::File {
                    var: file_var,
                    path: PathBuf::from(path),
                };
                source.read()?;
                Ok(Some(source))
            }
            None => Ok(None),
        }
    }

    fn read(&self) -> Result<Token, String> {
        match self {
            Source::Fixed(t) => Ok(t.clone()),
            Source::File { var, path } => read_file(path).map_err(|e| format!("${var} names {e}")),
        }
    }

    fn describe(&self) -> String {
        match self {
            Source::Fixed(_) => "set".into(),
            Source::File { var, .. } => format!("from ${var}, re-read"),
        }
    }
}

/// The coordinator's credentials: the cluster token and each role's key, re-read from their
/// files by [`Keyring::reload`]. Its `Debug` shows where each comes from, never a key.
pub struct Keyring {
    cluster: Option<Source>,
    roles: Vec<(Access, Source)>,
    keys: RwLock<Arc<Vec<(Access, Token)>>>,
}

impl std::fmt::Debug for Keyring {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Keyring({})", self.describe())
    }
}

impl Keyring {
    /// The credentials this coordinator's environment names: `$ASSAY_CLUSTER_TOKEN[_FILE]` and
    /// each role's `$ASSAY_<ROLE>_TOKEN[_FILE]`; `None` when none is set (every call accepted).
    /// An unreadable file or a malformed key is an error: a cluster meant to be protected must
    /// not start open.
    pub fn from_env() -> Result<Option<Keyring>, String> {
        let cluster = Source::from_env(Access::Admin)?;
        let mut roles = Vec::new();
        for role in Access::ROLES {
            if let Some(s) = Source::from_env(role)? {
                roles.push((role, s));
            }
        }
        Self::build(cluster, roles)
    }

    /// A keyring of fixed keys (tests, and callers that read keys themselves); `None` when
    /// there is none.
    pub fn fixed(
        cluster: Option<Token>,
        roles: Vec<(Access, Token)>,
    ) -> Result<Option<Keyring>, String> {
        Self::build(
            cluster.map(Source::Fixed),
            roles
                .into_iter()
                .map(|(r, t)| (r, Source::Fixed(t)))
                .collect(),
        )
    }

    fn build(
        cluster: Option<Source>,
        roles: Vec<(Access, Source)>,
    ) -> Result<Option<Keyring>, String> {
        if let Some((a, _)) = roles.iter().find(|(a, _)| *a == Access::Admin) {
            return Err(format!("{} is not a role key", a.credential()));
        }
        if cluster.is_none() && roles.is_empty() {
            return Ok(None);
        }
        let keyring = Keyring {
            cluster,
            roles,
            keys: RwLock::new(Arc::default()),
        };
        let keys = keyring.load()?;
        *keyring.keys.write().expect("keyring lock") = Arc::new(keys);
        Ok(Some(keyring))
    }

    /// Every key and what it grants: the cluster token (admin), then each role's own key or,
    /// without one, the key derived from the cluster token. Two credentials with the same key
    /// are an error (the coordinator could not tell which role presents it).
    fn load(&self) -> Result<Vec<(Access, Token)>, String> {
        let cluster = self.cluster.as_ref().map(Source::read).transpose()?;
        let mut keys = Vec::new();
        if let Some(t) = &cluster {
            keys.push((Access::Admin, t.clone()));
        }
        for role in Access::ROLES {
            match self.roles.iter().find(|(r, _)| *r == role) {
                Some((_, source)) => keys.push((role, source.read()?)),
                None => {
                    if let Some(t) = &cluster {
                        keys.push((role, t.role_key(role)));
                    }
                }
            }
        }
        for (i, (a, k)) in keys.iter().enumerate() {
            if let Some((b, _)) = keys[i + 1..].iter().find(|(_, other)| other == k) {
                return Err(format!(
                    "{} and {} are the same: each needs its own",
                    a.credential(),
                    b.credential()
                ));
            }
        }
        Ok(keys)
    }

    /// Reads the credential files again. `Ok(true)` when a key changed (from now on the new
    /// one is accepted and the old one refused); an unreadable file or a malformed key is an
    /// error and leaves the keys as they were (a Secret half updated must not lock everyone
    /// out, nor open the cluster).
    pub fn reload(&self) -> Result<bool, String> {
        let keys = self.load()?;
        let mut current = self.keys.write().expect("keyring lock");
        if **current == keys {
            return Ok(false);
        }
        *current = Arc::new(keys);
        Ok(true)
    }

    /// Whether [`Keyring::reload`] can change anything (some credential comes from a file).
    pub fn has_files(&self) -> bool {
        self.cluster
            .iter()
            .chain(self.roles.iter().map(|(_, s)| s))
            .any(|s| matches!(s, Source::File { .. }))
    }

    /// Where each credential comes from, for the log (never a key): `cluster token from
    /// $ASSAY_CLUSTER_TOKEN_FILE, re-read; worker key derived; …`.
    pub fn describe(&self) -> String {
        let mut parts = Vec::new();
        if let Some(s) = &self.cluster {
            parts.push(format!("cluster token {}", s.describe()));
        }
        for role in Access::ROLES {
            match self.roles.iter().find(|(r, _)| *r == role) {
                Some((_, s)) => parts.push(format!("{} key {}", role.name(), s.describe())),
                None if self.cluster.is_some() => {
                    parts.push(format!("{} key derived", role.name()))
                }
                None => parts.push(format!("no {} key", role.name())),
            }
        }
        parts.join("; ")
    }

    /// What the key `presented` grants; `None` when it is none of this keyring's. Every key is
    /// compared, each in time independent of where they differ.
    pub fn identify(&self, presented: &str) -> Option<Access> {
        let keys = self.keys.read().expect("keyring lock").clone();
        let mut found = None;
        for (access, key) in keys.iter() {
            if key.matches(presented) && found.is_none() {
                found = Some(*access);
            }
        }
        found
    }

    /// What the `authorization` metadata of a call grants: `UNAUTHENTICATED` without a bearer
    /// credential or with one this keyring does not know.
    pub fn authenticate(&self, authorization: Option<&str>) -> Result<Access, Status> {
        match authorization.and_then(|v| v.strip_prefix("Bearer ")) {
            Some(p) => self.identify(p).ok_or_else(|| {
                Status::unauthenticated(
                    "wrong cluster token or role key: this coordinator knows neither (set \
                     ASSAY_CLUSTER_TOKEN, or the key of your role, to the cluster's)",
                )
            }),
            None => Err(Status::unauthenticated(
                "this coordinator requires the cluster token or a role key (set \
                 ASSAY_CLUSTER_TOKEN, ASSAY_WORKER_TOKEN, ASSAY_SUBMITTER_TOKEN or \
                 ASSAY_VIEWER_TOKEN, or its _FILE variant)",
            )),
        }
    }

    /// The telemetry router's users: for every credential, its zenoh user and password
    /// ([`Credential::zenoh_login`]).
    pub fn zenoh_users(&self) -> Vec<(&'static str, String)> {
        let keys = self.keys.read().expect("keyring lock").clone();
        keys.iter()
            .map(|(access, key)| (access.zenoh_user(), key.derive("zenoh")))
            .collect()
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

/// Server side, for a service with one secret (a policy server, a frame relay): refuses every
/// request that does not carry the token (all pass when there is none). The coordinator checks
/// a [`Keyring`] instead.
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

    fn key(s: &str) -> Token {
        Token::new(s).unwrap()
    }

    #[test]
    fn role_keys_are_derived_distinct_and_identified() {
        let t = key("0123456789abcdef-secret");
        let keyring = Keyring::fixed(Some(t.clone()), Vec::new())
            .unwrap()
            .unwrap();
        let worker = t.role_key(Access::Worker);
        assert_eq!(worker, t.for_service("role/worker"));
        assert_eq!(t.role_key(Access::Admin), t);
        // The documented recipe (docs: hex SHA-256 of "assay/role/worker", NUL, the token).
        assert_eq!(
            worker.0.as_ref(),
            {
                use sha2::Digest;
                let mut h = sha2::Sha256::new();
                h.update(b"assay/role/worker\0");
                h.update(b"0123456789abcdef-secret");
                hex::encode(h.finalize())
            }
            .as_str()
        );
        for access in [
            Access::Admin,
            Access::Worker,
            Access::Submitter,
            Access::Viewer,
        ] {
            assert_eq!(keyring.identify(&t.role_key(access).0), Some(access));
        }
        // Keys of different roles differ, and none is a service's secret.
        let mut all: Vec<String> = [Access::Admin]
            .into_iter()
            .chain(Access::ROLES)
            .map(|a| t.role_key(a).0.to_string())
            .collect();
        all.push(t.derive("policy"));
        all.push(t.derive("zenoh"));
        let n = all.len();
        all.sort();
        all.dedup();
        assert_eq!(all.len(), n);
        assert_eq!(keyring.identify(&t.derive("policy")), None);
        assert_eq!(keyring.identify("0123456789abcdef-secre"), None);
        // Another cluster's worker key is not this one's.
        assert_eq!(
            keyring.identify(&key("another-cluster-token!!").role_key(Access::Worker).0),
            None
        );
        assert_eq!(
            keyring.describe(),
            "cluster token set; worker key derived; submitter key derived; viewer key derived"
        );
        assert!(!format!("{keyring:?}").contains("secret"));
    }

    #[test]
    fn an_explicit_role_key_replaces_the_derived_one() {
        let t = key("0123456789abcdef-secret");
        let own = key("the-viewers-own-key-0123");
        let keyring = Keyring::fixed(Some(t.clone()), vec![(Access::Viewer, own.clone())])
            .unwrap()
            .unwrap();
        assert_eq!(keyring.identify(&own.0), Some(Access::Viewer));
        assert_eq!(keyring.identify(&t.role_key(Access::Viewer).0), None);
        assert_eq!(
            keyring.identify(&t.role_key(Access::Worker).0),
            Some(Access::Worker)
        );
        // Without a cluster token, only the keys given.
        let only = Keyring::fixed(None, vec![(Access::Worker, own.clone())])
            .unwrap()
            .unwrap();
        assert_eq!(only.identify(&own.0), Some(Access::Worker));
        assert_eq!(only.zenoh_users(), vec![("worker", own.derive("zenoh"))]);
        assert_eq!(
            only.describe(),
            "worker key set; no submitter key; no viewer key"
        );
        assert!(Keyring::fixed(None, Vec::new()).unwrap().is_none());
        // One key for two roles is refused, naming them (not the key).
        let e = Keyring::fixed(
            None,
            vec![(Access::Worker, own.clone()), (Access::Submitter, own)],
        )
        .unwrap_err();
        assert_eq!(
            e,
            "a worker key and a submitter key are the same: each needs its own"
        );
        let e = Keyring::fixed(
            Some(t.clone()),
            vec![(Access::Submitter, t.role_key(Access::Worker))],
        )
        .unwrap_err();
        assert!(e.contains("a worker key and a submitter key"), "{e}");
    }

    #[test]
    fn calls_are_authenticated_with_reasons_that_show_no_key() {
        let t = key("0123456789abcdef-secret");
        let keyring = Keyring::fixed(Some(t.clone()), Vec::new())
            .unwrap()
            .unwrap();
        let bearer = |k: &Token| format!("Bearer {}", k.0);
        assert_eq!(
            keyring.authenticate(Some(&bearer(&t))).unwrap(),
            Access::Admin
        );
        assert_eq!(
            keyring
                .authenticate(Some(&bearer(&t.role_key(Access::Submitter))))
                .unwrap(),
            Access::Submitter
        );
        let e = keyring.authenticate(None).unwrap_err();
        assert_eq!(e.code(), tonic::Code::Unauthenticated);
        assert!(
            e.message()
                .contains("requires the cluster token or a role key")
        );
        let e = keyring
            .authenticate(Some("Bearer 0123456789abcdef-secreT"))
            .unwrap_err();
        assert_eq!(e.code(), tonic::Code::Unauthenticated);
        assert!(e.message().contains("wrong cluster token"));
        assert!(!e.message().contains("secre"));
        assert!(
            keyring.authenticate(Some(&t.0)).is_err(),
            "not a bearer credential"
        );
        // The router's users: the cluster token's as before roles, then one per role.
        let users = keyring.zenoh_users();
        assert_eq!(users[0], ("assay", t.derive("zenoh")));
        let c = Credential {
            access: Access::Viewer,
            token: t.role_key(Access::Viewer),
        };
        assert!(users.contains(&c.zenoh_login()));
        assert_eq!(c.zenoh_login().0, "viewer");
    }

    #[test]
    fn a_keyring_re_reads_its_files_and_keeps_its_keys_through_a_bad_read() {
        let dir = std::env::temp_dir().join(format!("assay-keyring-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("worker-key");
        let (old, new) = (
            key("the-old-worker-key-0123"),
            key("the-new-worker-key-4567"),
        );
        std::fs::write(&file, "the-old-worker-key-0123\n").unwrap();
        let keyring = Keyring::build(
            None,
            vec![(
                Access::Worker,
                Source::File {
                    var: "ASSAY_WORKER_TOKEN_FILE",
                    path: file.clone(),
                },
            )],
        )
        .unwrap()
        .unwrap();
        assert!(keyring.has_files());
        assert_eq!(keyring.identify(&old.0), Some(Access::Worker));
        assert!(!keyring.reload().unwrap(), "nothing changed");
        std::fs::write(&file, "the-new-worker-key-4567").unwrap();
        assert!(keyring.reload().unwrap());
        assert_eq!(keyring.identify(&new.0), Some(Access::Worker));
        assert_eq!(keyring.identify(&old.0), None);
        // A bad read is an error naming the variable and file, and the keys stay.
        std::fs::write(&file, "short").unwrap();
        let e = keyring.reload().unwrap_err();
        assert!(e.starts_with("$ASSAY_WORKER_TOKEN_FILE names "), "{e}");
        assert!(e.contains("at least 16"), "{e}");
        std::fs::remove_file(&file).unwrap();
        assert!(keyring.reload().unwrap_err().contains("cannot be read"));
        assert_eq!(keyring.identify(&new.0), Some(Access::Worker));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
