//! Requests on the control socket (one JSON object per datagram): the localisation module asks for a
//! relocalisation when its own uncertainty grows, or for the daemon's status.
//!
//! ```json
//! {"relocalise": {"reason": "particle filter diverged", "head_yaw": 0.3}}
//! {"relocalise": {"prior": {"pose": {"x": -2.0, "y": 1.0, "theta": 0.5,
//!                                    "sigma": {"x": 0.3, "y": 0.3, "theta": 0.2}, "age_s": 0.4}},
//!                 "own_half": true,
//!                 "ball": {"own": {"distance": 1.8, "bearing": 0.2},
//!                          "team": {"x": -0.5, "y": 0.8, "sigma": 0.3, "teammates": 3}}}}
//! {"belief": {"x": -2.0, "y": 1.0, "theta": 0.5, "sigma": {"x": 0.3, "y": 0.3, "theta": 0.2}}}
//! {"status": {}}
//! ```
//!
//! A relocalise request's context (`prior`, `own_half`, `ball`) is checked key by key: a part that is
//! malformed or out of range is left out, with an error naming it, and the request still stands.

use serde::{Deserialize, Serialize};
use thiserror::Error;

/// Datagrams longer than this are dropped before parsing.
pub const MAX_REQUEST_BYTES: usize = 4096;
/// Longest accepted reason, characters.
pub const MAX_REASON_CHARS: usize = 200;
/// Half the carpet's length (SPL 2025: 9 m field and 0.7 m border): poses and balls beyond are refused.
pub const CARPET_HALF_LENGTH_M: f64 = 5.2;
/// Half the carpet's width.
pub const CARPET_HALF_WIDTH_M: f64 = 3.7;
/// Farthest own ball observation accepted, metres.
pub const MAX_BALL_DISTANCE_M: f64 = 15.0;

/// A request on the control socket.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum ControlRequest {
    /// Relocalise now.
    Relocalise(RelocaliseRequest),
    /// The team's current pose estimate (the belief stream); not answered unless refused.
    Belief(PoseInput),
    /// Report counters and the last latencies.
    Status(StatusRequest),
}

/// `{"relocalise": {...}}`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(from = "RawRelocalise")]
pub struct RelocaliseRequest {
    /// Why, for the log and the published message.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
    /// The head yaw the frames will be taken with, radians (else the sensors' or the config's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub head_yaw: Option<f64>,
    /// The team's last belief: `{"pose": {...}}`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub prior: Option<PriorInput>,
    /// The robot is on its own half (`false` also turns off the goalkeeper's default).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub own_half: Option<bool>,
    /// The robot's own ball and the team's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ball: Option<BallInput>,
    /// Why parts of the context were left out, each naming its key.
    #[serde(skip)]
    pub context_errors: Vec<String>,
}

/// A pose estimate: `{"x", "y", "theta", "sigma": {"x", "y", "theta"}, "age_s"}` (metres, radians,
/// seconds); on the carpet, σ positive, age not negative.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseInput {
    /// Metres towards the opponent goal.
    pub x: f64,
    /// Metres to the left.
    pub y: f64,
    /// Heading, radians.
    pub theta: f64,
    /// Standard deviations.
    pub sigma: SigmaInput,
    /// How old the estimate is, seconds (0 when absent).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub age_s: Option<f64>,
}

/// Standard deviations of a pose: x, y (metres), theta (radians).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SigmaInput {
    /// Along x, metres.
    pub x: f64,
    /// Along y, metres.
    pub y: f64,
    /// Of the heading, radians.
    pub theta: f64,
}

/// `"prior": {"pose": {...}}`: the team's last belief.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PriorInput {
    /// The pose.
    pub pose: PoseInput,
}

/// `"ball": {"own": {...}, "team": {...}}`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BallInput {
    /// What the robot sees.
    pub own: OwnBallInput,
    /// What the team sees.
    pub team: TeamBallInput,
}

/// The robot's own ball: distance (metres) and bearing (radians, counter-clockwise from its heading).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OwnBallInput {
    /// Metres, 0 to [`MAX_BALL_DISTANCE_M`].
    pub distance: f64,
    /// Radians in [−π, π].
    pub bearing: f64,
}

/// The team's ball on the field: x, y, σ (metres) and how many teammates agree on it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TeamBallInput {
    /// Metres.
    pub x: f64,
    /// Metres.
    pub y: f64,
    /// Standard deviation, metres, positive.
    pub sigma: f64,
    /// Teammates agreeing on it, 1 to 20 (1 when absent).
    #[serde(default = "one")]
    pub teammates: u8,
}

fn one() -> u8 {
    1
}

/// A context value that cannot be used: the field and why.
#[derive(Clone, Debug, PartialEq)]
pub struct FieldError {
    /// The key, e.g. `relocalise.prior.pose.sigma.x`.
    pub field: String,
    /// What is wrong.
    pub reason: String,
}

impl std::fmt::Display for FieldError {
    fn fmt(&self, formatter: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(formatter, "{}: {}", self.field, self.reason)
    }
}

fn field_error(field: impl Into<String>, reason: impl Into<String>) -> FieldError {
    FieldError { field: field.into(), reason: reason.into() }
}

fn check_finite(field: &str, value: f64) -> Result<(), FieldError> {
    if value.is_finite() {
        Ok(())
    } else {
        Err(field_error(field, format!("{value} is not a finite number")))
    }
}

fn check_on_carpet(field: &str, x: f64, y: f64) -> Result<(), FieldError> {
    check_finite(&format!("{field}.x"), x)?;
    check_finite(&format!("{field}.y"), y)?;
    if x.abs() > CARPET_HALF_LENGTH_M || y.abs() > CARPET_HALF_WIDTH_M {
        return Err(field_error(
            field,
            format!(
                "({x}, {y}) m is off the carpet: expected |x| ≤ {CARPET_HALF_LENGTH_M} and |y| ≤ {CARPET_HALF_WIDTH_M}"
            ),
        ));
    }
    Ok(())
}

fn check_positive(field: &str, value: f64) -> Result<(), FieldError> {
    check_finite(field, value)?;
    if value > 0.0 {
        Ok(())
    } else {
        Err(field_error(field, format!("{value} is not a positive standard deviation")))
    }
}

impl PoseInput {
    /// Checks every value; `field` names the pose in errors (e.g. `relocalise.prior.pose`).
    pub fn validate(&self, field: &str) -> Result<(), FieldError> {
        check_on_carpet(field, self.x, self.y)?;
        check_finite(&format!("{field}.theta"), self.theta)?;
        check_positive(&format!("{field}.sigma.x"), self.sigma.x)?;
        check_positive(&format!("{field}.sigma.y"), self.sigma.y)?;
        check_positive(&format!("{field}.sigma.theta"), self.sigma.theta)?;
        if let Some(age) = self.age_s {
            check_finite(&format!("{field}.age_s"), age)?;
            if age < 0.0 {
                return Err(field_error(format!("{field}.age_s"), format!("{age} s is negative")));
            }
        }
        Ok(())
    }
}

impl BallInput {
    /// Checks every value.
    pub fn validate(&self) -> Result<(), FieldError> {
        let own = &self.own;
        check_finite("relocalise.ball.own.distance", own.distance)?;
        if !(0.0..=MAX_BALL_DISTANCE_M).contains(&own.distance) {
            return Err(field_error(
                "relocalise.ball.own.distance",
                format!("{} m is not in [0, {MAX_BALL_DISTANCE_M}]", own.distance),
            ));
        }
        check_finite("relocalise.ball.own.bearing", own.bearing)?;
        if own.bearing.abs() > std::f64::consts::PI {
            return Err(field_error(
                "relocalise.ball.own.bearing",
                format!("{} is not in [-pi, pi]", own.bearing),
            ));
        }
        check_on_carpet("relocalise.ball.team", self.team.x, self.team.y)?;
        check_positive("relocalise.ball.team.sigma", self.team.sigma)?;
        if !(1..=20).contains(&self.team.teammates) {
            return Err(field_error(
                "relocalise.ball.team.teammates",
                format!("{} is not in 1..=20", self.team.teammates),
            ));
        }
        Ok(())
    }
}

/// What arrives: the context keys as plain JSON, checked one by one in [`RelocaliseRequest::from`].
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawRelocalise {
    #[serde(default)]
    reason: Option<String>,
    #[serde(default)]
    head_yaw: Option<f64>,
    #[serde(default)]
    prior: Option<serde_json::Value>,
    #[serde(default)]
    own_half: Option<serde_json::Value>,
    #[serde(default)]
    ball: Option<serde_json::Value>,
}

/// Parses one context key, or says why not, naming the key (serde's message names an unknown or
/// missing key inside it).
fn context_value<T: serde::de::DeserializeOwned>(
    key: &str,
    value: Option<serde_json::Value>,
    check: impl Fn(&T) -> Result<(), FieldError>,
    errors: &mut Vec<String>,
) -> Option<T> {
    let parsed = serde_json::from_value::<T>(value?)
        .map_err(|error| field_error(key, error.to_string()))
        .and_then(|parsed| check(&parsed).map(|()| parsed));
    parsed.map_err(|error| errors.push(error.to_string())).ok()
}

impl From<RawRelocalise> for RelocaliseRequest {
    fn from(raw: RawRelocalise) -> Self {
        let mut context_errors = Vec::new();
        let prior = context_value(
            "relocalise.prior",
            raw.prior,
            |prior: &PriorInput| prior.pose.validate("relocalise.prior.pose"),
            &mut context_errors,
        );
        let own_half =
            context_value("relocalise.own_half", raw.own_half, |_: &bool| Ok(()), &mut context_errors);
        let ball = context_value("relocalise.ball", raw.ball, BallInput::validate, &mut context_errors);
        Self { reason: raw.reason, head_yaw: raw.head_yaw, prior, own_half, ball, context_errors }
    }
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
    #[error(
        "control request is not {{\"relocalise\": {{...}}}}, {{\"belief\": {{...}}}} or {{\"status\": {{}}}}: {0}"
    )]
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
        if let ControlRequest::Belief(belief) = &request {
            belief
                .validate("belief")
                .map_err(|error| ControlError::Invalid { field: "belief", reason: error.to_string() })?;
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
                head_yaw: Some(0.3),
                ..RelocaliseRequest::default()
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

    const CONTEXT: &str = r#"{"relocalise": {"prior": {"pose": {"x": -2.0, "y": 1.0, "theta": 0.5,
        "sigma": {"x": 0.3, "y": 0.3, "theta": 0.2}, "age_s": 0.4}}, "own_half": true,
        "ball": {"own": {"distance": 1.8, "bearing": 0.2}, "team": {"x": -0.5, "y": 0.8, "sigma": 0.3, "teammates": 3}}}}"#;

    fn relocalise(text: &str) -> RelocaliseRequest {
        match ControlRequest::parse(text.as_bytes()) {
            Ok(ControlRequest::Relocalise(request)) => request,
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn context_parses_and_round_trips() {
        let request = relocalise(CONTEXT);
        assert!(request.context_errors.is_empty(), "{:?}", request.context_errors);
        assert_eq!(request.prior.unwrap().pose.sigma.theta, 0.2);
        assert_eq!(request.own_half, Some(true));
        assert_eq!(request.ball.unwrap().team.teammates, 3);
        let json = serde_json::to_vec(&ControlRequest::Relocalise(request.clone())).unwrap();
        assert_eq!(ControlRequest::parse(&json), Ok(ControlRequest::Relocalise(request)));
        let belief =
            br#"{"belief": {"x": 1, "y": 2, "theta": 3, "sigma": {"x": 0.1, "y": 0.1, "theta": 0.1}}}"#;
        assert!(
            matches!(ControlRequest::parse(belief), Ok(ControlRequest::Belief(pose)) if pose.age_s.is_none())
        );
    }

    #[test]
    fn bad_context_is_left_out_with_an_error_naming_the_key_and_the_request_stands() {
        let cases = [
            (
                CONTEXT.replace("\"x\": -2.0", "\"x\": -9.0"),
                "relocalise.prior.pose: (-9, 1) m is off the carpet",
            ),
            (
                CONTEXT.replace("\"x\": 0.3", "\"x\": -0.3"),
                "relocalise.prior.pose.sigma.x: -0.3 is not a positive",
            ),
            (
                CONTEXT.replace("\"age_s\": 0.4", "\"age_s\": -1"),
                "relocalise.prior.pose.age_s: -1 s is negative",
            ),
            (CONTEXT.replace("\"age_s\"", "\"age\""), "relocalise.prior: unknown field `age`"),
            (CONTEXT.replace("\"own_half\": true", "\"own_half\": 1"), "relocalise.own_half: invalid type"),
            (CONTEXT.replace("\"distance\": 1.8", "\"distance\": 99"), "relocalise.ball.own.distance: 99 m"),
            (
                CONTEXT.replace("\"sigma\": 0.3", "\"sigma\": 0"),
                "relocalise.ball.team.sigma: 0 is not a positive",
            ),
            (CONTEXT.replace("\"teammates\": 3", "\"teammates\": 0"), "relocalise.ball.team.teammates: 0"),
            (CONTEXT.replace("\"teammates\"", "\"mates\""), "relocalise.ball: unknown field `mates`"),
            (
                CONTEXT
                    .replace(", \"team\": {\"x\": -0.5, \"y\": 0.8, \"sigma\": 0.3, \"teammates\": 3}", ""),
                "relocalise.ball: missing field `team`",
            ),
        ];
        for (text, expected) in cases {
            let request = relocalise(&text);
            assert_eq!(request.context_errors.len(), 1, "{text}: {:?}", request.context_errors);
            assert!(request.context_errors[0].starts_with(expected), "{}", request.context_errors[0]);
            let kept = [request.prior.is_some(), request.own_half.is_some(), request.ball.is_some()];
            assert_eq!(kept.iter().filter(|kept| **kept).count(), 2, "only the bad part is left out: {text}");
        }
        // NaN and infinities are not JSON (serde refuses 1e999 as out of range); checked all the same.
        let nan = PoseInput { theta: f64::NAN, ..relocalise(CONTEXT).prior.unwrap().pose };
        let error = nan.validate("belief").unwrap_err().to_string();
        assert!(error.starts_with("belief.theta: NaN is not a finite"), "{error}");
        let belief =
            br#"{"belief": {"x": 1, "y": 2, "theta": 3, "sigma": {"x": 0.1, "y": -0.1, "theta": 0.1}}}"#;
        let error = ControlRequest::parse(belief).unwrap_err().to_string();
        assert!(error.contains("belief.sigma.y: -0.1 is not a positive"), "{error}");
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
