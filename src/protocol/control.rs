//! Requests on the control socket (one JSON object per datagram): the localisation module asks for a
//! relocalisation when its own uncertainty grows, or for the daemon's status.
//!
//! ```json
//! {"relocalise": {"reason": "particle filter diverged", "head_yaw": 0.3}}
//! {"status": {}}
//! ```

use serde::{Deserialize, Serialize};
use thiserror::Error;

/// Datagrams longer than this are dropped before parsing.
pub const MAX_REQUEST_BYTES: usize = 4096;
/// Longest accepted reason, characters.
pub const MAX_REASON_CHARS: usize = 200;

/// A request on the control socket.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum ControlRequest {
    /// Relocalise now.
    Relocalise(RelocaliseRequest),
    /// Report counters and the last latencies.
    Status(StatusRequest),
}

/// `{"relocalise": {...}}`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RelocaliseRequest {
    /// Why, for the log and the published message.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
    /// The head yaw the frames will be taken with, radians (else the sensors' or the config's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub head_yaw: Option<f64>,
}

/// `{"status": {}}`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StatusRequest {}

/// Why a datagram is not a request.
#[derive(Debug, Error, PartialEq)]
pub enum ControlError {
    /// Too long to parse.
    #[error("control request of {0} bytes is longer than {MAX_REQUEST_BYTES}")]
    TooLong(usize),
    /// Not one of the requests.
    #[error("control request is not {{\"relocalise\": {{...}}}} or {{\"status\": {{}}}}: {0}")]
    Malformed(String),
    /// A value out of range.
    #[error("control request field {field}: {reason}")]
    Invalid {
        /// The field.
        field: &'static str,
        /// What is wrong.
        reason: String,
    },
}

impl ControlRequest {
    /// Parses and checks one datagram.
    pub fn parse(bytes: &[u8]) -> Result<Self, ControlError> {
        if bytes.len() > MAX_REQUEST_BYTES {
            return Err(ControlError::TooLong(bytes.len()));
        }
        let request: Self =
            serde_json::from_slice(bytes).map_err(|error| ControlError::Malformed(error.to_string()))?;
        if let ControlRequest::Relocalise(relocalise) = &request {
            if let Some(yaw) = relocalise.head_yaw
                && !(-std::f64::consts::PI..=std::f64::consts::PI).contains(&yaw)
            {
                return Err(ControlError::Invalid {
                    field: "relocalise.head_yaw",
                    reason: format!("{yaw} is not in [-pi, pi] radians"),
                });
            }
            if let Some(reason) = &relocalise.reason
                && reason.chars().count() > MAX_REASON_CHARS
            {
                return Err(ControlError::Invalid {
                    field: "relocalise.reason",
                    reason: format!("longer than {MAX_REASON_CHARS} characters"),
                });
            }
        }
        Ok(request)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn requests_parse() {
        assert_eq!(
            ControlRequest::parse(br#"{"relocalise": {"reason": "diverged", "head_yaw": 0.3}}"#),
            Ok(ControlRequest::Relocalise(RelocaliseRequest {
                reason: Some("diverged".into()),
                head_yaw: Some(0.3)
            }))
        );
        assert_eq!(
            ControlRequest::parse(br#"{"relocalise": {}}"#),
            Ok(ControlRequest::Relocalise(RelocaliseRequest::default()))
        );
        assert_eq!(ControlRequest::parse(br#"{"status": {}}"#), Ok(ControlRequest::Status(StatusRequest {})));
    }

    #[test]
    fn bad_requests_say_why() {
        let error = |bytes: &[u8]| ControlRequest::parse(bytes).unwrap_err();
        assert!(matches!(error(b"{\"reboot\": {}}"), ControlError::Malformed(_)));
        assert!(matches!(error(b"{\"relocalise\": {\"yaw\": 1}}"), ControlError::Malformed(_)));
        assert!(matches!(error(b"\xff\x00"), ControlError::Malformed(_)));
        assert!(matches!(
            error(br#"{"relocalise": {"head_yaw": 4.0}}"#),
            ControlError::Invalid { field: "relocalise.head_yaw", .. }
        ));
        let long = format!(r#"{{"relocalise": {{"reason": "{}"}}}}"#, "x".repeat(MAX_REASON_CHARS + 1));
        assert!(matches!(error(long.as_bytes()), ControlError::Invalid { field: "relocalise.reason", .. }));
        assert_eq!(error(&[b' '; MAX_REQUEST_BYTES + 1]), ControlError::TooLong(MAX_REQUEST_BYTES + 1));
    }

    proptest! {
        #[test]
        fn any_bytes_give_a_checked_request_or_an_error(bytes in prop::collection::vec(any::<u8>(), 0..256)) {
            if let Ok(ControlRequest::Relocalise(request)) = ControlRequest::parse(&bytes) {
                prop_assert!(request.head_yaw.is_none_or(|yaw| yaw.abs() <= std::f64::consts::PI));
            }
        }

        #[test]
        fn any_head_yaw_in_range_is_accepted(yaw in -3.0f64..3.0) {
            let text = format!(r#"{{"relocalise": {{"head_yaw": {yaw}}}}}"#);
            let ControlRequest::Relocalise(request) = ControlRequest::parse(text.as_bytes()).unwrap() else {
                panic!("not a relocalise request");
            };
            prop_assert!((request.head_yaw.unwrap() - yaw).abs() < 1e-12);
        }
    }
}
