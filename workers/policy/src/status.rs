//! The one place where [`PolicyError`] and gRPC status codes meet (both directions), as the
//! service documents them in `proto/assay/v1/policy.proto`.

use assay_model::policy::PolicyError;
use tonic::{Code, Status};

/// The status a server answers when its policy fails.
pub(crate) fn to_status(e: PolicyError) -> Status {
    match e {
        PolicyError::Unavailable(m) => Status::unavailable(m),
        PolicyError::BadAnswer(m) => Status::internal(m),
        PolicyError::Load(m) => Status::failed_precondition(m),
    }
}

/// The error a client reports for a failed call: `what` names the server and the call (e.g.
/// "policy server at http://h:1 failed Act at step 3"). Errors of the connection itself (no
/// server, a broken stream) and the retryable codes are [`PolicyError::Unavailable`]; a server that
/// cannot build the policy is [`PolicyError::Load`]; a policy that failed is
/// [`PolicyError::BadAnswer`].
pub(crate) fn from_status(what: &str, s: &Status) -> PolicyError {
    // A status made by the client from a transport error carries that error as its source; one
    // answered by a server does not.
    if let Some(source) = std::error::Error::source(s) {
        return PolicyError::Unavailable(format!("{what}: {}", error_chain(source)));
    }
    let message = format!("{what}: {} ({:?})", s.message(), s.code());
    match s.code() {
        Code::Unavailable
        | Code::DeadlineExceeded
        | Code::Cancelled
        | Code::ResourceExhausted
        | Code::Aborted
        | Code::Unknown
        | Code::NotFound => PolicyError::Unavailable(message),
        Code::FailedPrecondition | Code::Unimplemented | Code::Unauthenticated => {
            PolicyError::Load(message)
        }
        _ => PolicyError::BadAnswer(message),
    }
}

/// An error with its causes ("transport error: tcp connect error: Connection refused"), each
/// cause once (some errors repeat their source in their own message).
pub(crate) fn error_chain(e: &dyn std::error::Error) -> String {
    let mut s = e.to_string();
    let mut source = e.source();
    while let Some(cause) = source {
        let text = cause.to_string();
        if !s.ends_with(&text) {
            s.push_str(": ");
            s.push_str(&text);
        }
        source = cause.source();
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn policy_errors_survive_the_wire() {
        for e in [
            PolicyError::Unavailable("busy".into()),
            PolicyError::BadAnswer("nan".into()),
            PolicyError::Load("no model".into()),
        ] {
            let back = from_status("act", &to_status(e.clone()));
            assert_eq!(
                std::mem::discriminant(&back),
                std::mem::discriminant(&e),
                "{e} came back as {back}"
            );
        }
        assert!(from_status("act", &Status::not_found("episode e1")).retryable());
        assert!(!from_status("act", &Status::invalid_argument("frame")).retryable());
    }
}
