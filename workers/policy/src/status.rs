//! The one place where [`PolicyError`] and gRPC status codes meet (both directions), as the
//! service documents them in `proto/assay/v1/policy.proto`: the status a server answers for an
//! error ([`to_status`]), and the error a client makes of a code ([`from_code`]; the codes every
//! client treats as retryable are [`crate::grpc`]'s). Never: calls, connections, wording.

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

/// The error a policy client reports for a status the server answered with a code that is not
/// retryable ([`crate::grpc::from_status`] makes the retryable ones and lost connections
/// [`PolicyError::Unavailable`]): a server that cannot build the policy is [`PolicyError::Load`];
/// a policy that failed is [`PolicyError::BadAnswer`]. `message` names the server and the call.
pub(crate) fn from_code(code: Code, message: String) -> PolicyError {
    match code {
        Code::FailedPrecondition | Code::Unimplemented | Code::Unauthenticated => {
            PolicyError::Load(message)
        }
        _ => PolicyError::BadAnswer(message),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn from_status(what: &str, s: &Status) -> PolicyError {
        crate::grpc::from_status::<crate::remote::Client>(what, s)
    }

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
