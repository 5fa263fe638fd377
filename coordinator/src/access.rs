//! Who may call what: the coordinator's table of RPC methods and the roles that may call each,
//! and [`Guarded`], which checks every call against it before the service sees it.
//!
//! Owns: the method → roles table ([`allowed`]) and the check (the credential's role from the
//! [`Keyring`], then the table). Never reads credentials itself (the keyring does), never looks
//! inside a message: a role may call a method or not, whatever the batch.
//!
//! The cluster token may call everything. A method missing from the table is the cluster
//! token's alone (`tests` fails when a `.proto` gains a method the table lacks).

use std::convert::Infallible;
use std::sync::Arc;
use std::task::{Context, Poll};

use assay_proto::auth::{Access, Keyring};
use tonic::body::Body;
use tonic::codegen::{BoxFuture, Service, http};
use tonic::server::NamedService;

const WORKER: &[Access] = &[Access::Worker];
const SUBMITTER: &[Access] = &[Access::Submitter];
const READER: &[Access] = &[Access::Submitter, Access::Viewer];

/// Every method of the coordinator's services (gRPC path) and the roles that may call it.
const TABLE: &[(&str, &[Access])] = &[
    ("/assay.v1.WorkerSession/Session", WORKER),
    ("/assay.v1.Coordinator/SubmitBatch", SUBMITTER),
    ("/assay.v1.Coordinator/SubmitBatchStream", SUBMITTER),
    ("/assay.v1.Coordinator/CancelBatch", SUBMITTER),
    ("/assay.v1.Coordinator/GetBatch", READER),
    ("/assay.v1.Coordinator/ListBatches", READER),
    ("/assay.v1.Coordinator/WatchBatch", READER),
    ("/assay.v1.Coordinator/GetReport", READER),
];

/// The roles that may call `path` (`/assay.v1.Coordinator/SubmitBatch`) besides the cluster
/// token; none for a method the table does not know.
pub fn allowed(path: &str) -> &'static [Access] {
    TABLE
        .iter()
        .find(|(p, _)| *p == path)
        .map_or(&[], |(_, roles)| roles)
}

/// Whether a credential of `access` may call `path`: `PERMISSION_DENIED` naming the credential,
/// the method and what it takes, when not.
pub fn check(access: Access, path: &str) -> Result<(), tonic::Status> {
    let roles = allowed(path);
    if access == Access::Admin || roles.contains(&access) {
        return Ok(());
    }
    let method = path.trim_start_matches("/assay.v1.");
    let takes: Vec<String> = roles
        .iter()
        .map(|r| r.credential())
        .chain(["the cluster token".to_owned()])
        .collect();
    Err(tonic::Status::permission_denied(format!(
        "{} may not call {method}: it takes {}",
        access.credential(),
        takes.join(" or ")
    )))
}

/// A service of the coordinator behind the credential check: with a keyring, every call
/// carries a credential it knows (else `UNAUTHENTICATED`) whose role may call the method (else
/// `PERMISSION_DENIED`); without one, every call passes.
#[derive(Clone)]
pub struct Guarded<S> {
    inner: S,
    keyring: Option<Arc<Keyring>>,
}

impl<S> Guarded<S> {
    pub fn new(inner: S, keyring: Option<Arc<Keyring>>) -> Self {
        Self { inner, keyring }
    }

    fn admit(&self, req: &http::Request<Body>) -> Result<(), tonic::Status> {
        let Some(keyring) = &self.keyring else {
            return Ok(());
        };
        let authorization = req
            .headers()
            .get(http::header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok());
        let access = keyring.authenticate(authorization)?;
        check(access, req.uri().path())
    }
}

impl<S> Service<http::Request<Body>> for Guarded<S>
where
    S: Service<http::Request<Body>, Response = http::Response<Body>, Error = Infallible>,
    S::Future: Send + 'static,
{
    type Response = http::Response<Body>;
    type Error = Infallible;
    type Future = BoxFuture<Self::Response, Infallible>;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), Infallible>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, req: http::Request<Body>) -> Self::Future {
        match self.admit(&req) {
            Ok(()) => Box::pin(self.inner.call(req)),
            Err(status) => Box::pin(async move { Ok(status.into_http()) }),
        }
    }
}

impl<S: NamedService> NamedService for Guarded<S> {
    const NAME: &'static str = S::NAME;
}

#[cfg(test)]
mod tests {
    use super::*;
    use assay_proto::auth::Token;

    const SUBMIT: &str = "/assay.v1.Coordinator/SubmitBatch";
    const SUBMIT_STREAM: &str = "/assay.v1.Coordinator/SubmitBatchStream";
    const CANCEL: &str = "/assay.v1.Coordinator/CancelBatch";
    const SESSION: &str = "/assay.v1.WorkerSession/Session";
    const READS: [&str; 4] = [
        "/assay.v1.Coordinator/GetBatch",
        "/assay.v1.Coordinator/ListBatches",
        "/assay.v1.Coordinator/WatchBatch",
        "/assay.v1.Coordinator/GetReport",
    ];

    #[test]
    fn each_role_may_call_exactly_its_methods() {
        use Access::*;
        for (path, may) in [
            (SESSION, vec![Admin, Worker]),
            (SUBMIT, vec![Admin, Submitter]),
            (SUBMIT_STREAM, vec![Admin, Submitter]),
            (CANCEL, vec![Admin, Submitter]),
        ]
        .into_iter()
        .chain(READS.map(|p| (p, vec![Admin, Submitter, Viewer])))
        {
            for access in [Admin, Worker, Submitter, Viewer] {
                assert_eq!(
                    check(access, path).is_ok(),
                    may.contains(&access),
                    "{access:?} on {path}"
                );
            }
        }
        // An unknown method is the cluster token's alone.
        for access in Access::ROLES {
            assert!(check(access, "/assay.v1.Coordinator/DropEverything").is_err());
        }
        assert!(check(Admin, "/assay.v1.Coordinator/DropEverything").is_ok());
    }

    #[test]
    fn a_refusal_says_who_may_call_the_method() {
        let e = check(Access::Worker, SUBMIT).unwrap_err();
        assert_eq!(e.code(), tonic::Code::PermissionDenied);
        assert_eq!(
            e.message(),
            "a worker key may not call Coordinator/SubmitBatch: it takes a submitter key or the \
             cluster token"
        );
        let e = check(Access::Submitter, SESSION).unwrap_err();
        assert_eq!(
            e.message(),
            "a submitter key may not call WorkerSession/Session: it takes a worker key or the \
             cluster token"
        );
        let e = check(Access::Worker, READS[3]).unwrap_err();
        assert_eq!(
            e.message(),
            "a worker key may not call Coordinator/GetReport: it takes a submitter key or a \
             viewer key or the cluster token"
        );
    }

    /// Every RPC of the coordinator's services is in the table: a method added to a `.proto`
    /// without a row would be the cluster token's alone, silently.
    #[test]
    fn the_table_covers_every_method_of_the_protos() {
        let protos = [
            (
                "Coordinator",
                include_str!("../../proto/assay/v1/coordinator.proto"),
            ),
            (
                "WorkerSession",
                include_str!("../../proto/assay/v1/worker.proto"),
            ),
        ];
        let mut seen = 0;
        for (service, text) in protos {
            for line in text.lines() {
                let Some(rest) = line.trim().strip_prefix("rpc ") else {
                    continue;
                };
                let method = rest.split('(').next().unwrap().trim();
                let path = format!("/assay.v1.{service}/{method}");
                assert!(!allowed(&path).is_empty(), "{path} is not in the table");
                seen += 1;
            }
        }
        assert_eq!(seen, TABLE.len(), "the table names a method no .proto has");
    }

    #[test]
    fn guarded_services_refuse_before_the_service_runs() {
        #[derive(Clone)]
        struct Ok200;
        impl Service<http::Request<Body>> for Ok200 {
            type Response = http::Response<Body>;
            type Error = Infallible;
            type Future = BoxFuture<Self::Response, Infallible>;
            fn poll_ready(&mut self, _: &mut Context<'_>) -> Poll<Result<(), Infallible>> {
                Poll::Ready(Ok(()))
            }
            fn call(&mut self, _: http::Request<Body>) -> Self::Future {
                Box::pin(async { Ok(http::Response::new(Body::default())) })
            }
        }
        let t = Token::new("0123456789abcdef-secret").unwrap();
        let keyring = Arc::new(
            Keyring::fixed(Some(t.clone()), Vec::new())
                .unwrap()
                .unwrap(),
        );
        let rt = tokio::runtime::Builder::new_current_thread()
            .build()
            .unwrap();
        let call = |path: &str, key: Option<Token>, keyring: Option<Arc<Keyring>>| {
            let mut req = http::Request::builder().uri(path);
            if let Some(k) = key {
                // The header as a client's `AttachToken` writes it.
                let mut r = tonic::Request::new(());
                let mut attach = assay_proto::auth::AttachToken::new(Some(k));
                r = tonic::service::Interceptor::call(&mut attach, r).unwrap();
                let v = r
                    .metadata()
                    .get("authorization")
                    .unwrap()
                    .to_str()
                    .unwrap()
                    .to_owned();
                req = req.header("authorization", v);
            }
            let resp = rt
                .block_on(Guarded::new(Ok200, keyring).call(req.body(Body::default()).unwrap()))
                .unwrap();
            tonic::Status::from_header_map(resp.headers()).map(|s| s.code())
        };
        let k = Some(keyring);
        assert_eq!(call(SUBMIT, Some(t.clone()), k.clone()), None);
        assert_eq!(
            call(SUBMIT, Some(t.role_key(Access::Submitter)), k.clone()),
            None
        );
        assert_eq!(
            call(SUBMIT, Some(t.role_key(Access::Viewer)), k.clone()),
            Some(tonic::Code::PermissionDenied)
        );
        assert_eq!(
            call(SUBMIT, None, k.clone()),
            Some(tonic::Code::Unauthenticated)
        );
        assert_eq!(call(SESSION, Some(t.role_key(Access::Worker)), k), None);
        assert_eq!(
            call(SUBMIT, None, None),
            None,
            "no keyring: an open coordinator"
        );
    }
}
