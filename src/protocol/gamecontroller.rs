//! The GameController's control packet (`RoboCupGameControlData`, struct version 18, 118 bytes,
//! little-endian, no padding) and the kidnap trigger it carries: our player's penalty ending after a
//! penalty that took the robot off the field.
//!
//! Every field is checked; a packet with a wrong size, header, version or an out-of-range value is
//! rejected with the reason, so a daemon can log it and go on.

use std::net::IpAddr;

use thiserror::Error;

/// UDP port the GameController broadcasts control packets to.
pub const CONTROL_PORT: u16 = 3838;
/// Size of a version-18 control packet, bytes.
pub const PACKET_SIZE: usize = 118;
/// The packet's header.
pub const HEADER: [u8; 4] = *b"RGme";
/// The struct version decoded here.
pub const VERSION: u8 = 18;
/// Robot slots per team in the packet.
pub const MAX_PLAYERS: usize = 20;

const TEAM_SIZE: usize = 10 + 2 * MAX_PLAYERS;
const TEAMS_OFFSET: usize = 18;

/// Why bytes are not a control packet.
#[derive(Debug, Error, PartialEq, Eq)]
pub enum PacketError {
    /// Wrong length.
    #[error("control packet has {0} bytes, expected {PACKET_SIZE}")]
    WrongSize(usize),
    /// Not a control packet.
    #[error("control packet header is {0:?}, expected \"RGme\"")]
    WrongHeader([u8; 4]),
    /// Another struct version.
    #[error("control packet struct version {0}, expected {VERSION}")]
    WrongVersion(u8),
    /// A field holds a value the protocol does not define.
    #[error("control packet field {field} is {value}: {expected}")]
    Invalid {
        /// The field.
        field: &'static str,
        /// Its value.
        value: i64,
        /// What is allowed.
        expected: &'static str,
    },
}

macro_rules! coded_enum {
    ($(#[$meta:meta])* $name:ident, $field:literal { $($(#[$vmeta:meta])* $variant:ident = $code:literal),+ $(,)? }) => {
        $(#[$meta])*
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize)]
        #[serde(rename_all = "snake_case")]
        pub enum $name { $($(#[$vmeta])* $variant),+ }

        impl $name {
            fn decode(code: u8) -> Result<Self, PacketError> {
                match code {
                    $($code => Ok(Self::$variant),)+
                    _ => Err(PacketError::Invalid {
                        field: $field,
                        value: code.into(),
                        expected: concat!("one of ", $(stringify!($code), " "),+),
                    }),
                }
            }

            fn code(self) -> u8 {
                match self { $(Self::$variant => $code),+ }
            }
        }
    };
}

coded_enum!(
    /// The game state.
    GameState, "state" {
        /// Before the game.
        Initial = 0,
        /// Walking to kick-off positions.
        Ready = 1,
        /// Waiting for kick-off.
        Set = 2,
        /// Playing.
        Playing = 3,
        /// Half or game over.
        Finished = 4,
        /// Waiting before the game.
        Standby = 5,
    }
);

coded_enum!(
    /// The game phase.
    GamePhase, "gamePhase" {
        /// Normal play.
        Normal = 0,
        /// Penalty shoot-out.
        PenaltyShootout = 1,
        /// Overtime.
        Overtime = 2,
        /// Timeout.
        Timeout = 3,
    }
);

coded_enum!(
    /// The set play in progress.
    SetPlay, "setPlay" {
        /// None.
        None = 0,
        /// Goal kick.
        GoalKick = 1,
        /// Pushing free kick.
        PushingFreeKick = 2,
        /// Corner kick.
        CornerKick = 3,
        /// Kick-in.
        KickIn = 4,
        /// Penalty kick.
        PenaltyKick = 5,
    }
);

coded_enum!(
    /// A robot's penalty.
    Penalty, "penalty" {
        /// Not penalised.
        None = 0,
        /// Illegal ball contact.
        IllegalBallContact = 1,
        /// Pushing.
        PlayerPushing = 2,
        /// Moved in Set (penalised in place).
        IllegalMotionInSet = 3,
        /// Inactive player.
        InactivePlayer = 4,
        /// Illegal position.
        IllegalPosition = 5,
        /// Left the field.
        LeavingTheField = 6,
        /// Request for pick-up.
        RequestForPickup = 7,
        /// Local game stuck.
        LocalGameStuck = 8,
        /// Illegal position in Set.
        IllegalPositionInSet = 9,
        /// Player stance.
        PlayerStance = 10,
        /// Moved in Standby (penalised in place).
        IllegalMotionInStandby = 11,
        /// Substitute.
        Substitute = 14,
        /// Set by hand.
        Manual = 15,
    }
);

impl Penalty {
    /// Whether the referee takes the robot off the field for this penalty, so that it comes back
    /// somewhere else: everything but the in-place motion penalties.
    pub fn moves_robot(self) -> bool {
        !matches!(self, Penalty::None | Penalty::IllegalMotionInSet | Penalty::IllegalMotionInStandby)
    }
}

/// One robot slot of a team.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct RobotInfo {
    /// Its penalty.
    pub penalty: Penalty,
    /// Seconds until the penalty ends.
    pub secs_till_unpenalised: u8,
}

/// One team's part of the packet.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct TeamInfo {
    /// The team number.
    pub team_number: u8,
    /// Field player jersey colour (0 blue … 9 grey).
    pub field_player_colour: u8,
    /// Goalkeeper jersey colour.
    pub goalkeeper_colour: u8,
    /// The goalkeeper's player number.
    pub goalkeeper: u8,
    /// Goals scored.
    pub score: u8,
    /// Penalty shots taken.
    pub penalty_shot: u8,
    /// Bit per successful penalty shot.
    pub single_shots: u16,
    /// Team messages left.
    pub message_budget: u16,
    /// Robot slots; player number n is index n − 1.
    pub players: [RobotInfo; MAX_PLAYERS],
}

impl TeamInfo {
    /// The robot with 1-based player number `player`, if there is such a slot.
    pub fn player(&self, player: u8) -> Option<&RobotInfo> {
        self.players.get(usize::from(player).checked_sub(1)?)
    }
}

/// A decoded and validated control packet.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct GameControlData {
    /// Packet number (wraps at 255).
    pub packet_number: u8,
    /// Players per team.
    pub players_per_team: u8,
    /// 0 round robin, 1 play-off.
    pub competition_phase: u8,
    /// 0 normal, 1 most passes.
    pub competition_type: u8,
    /// The game phase.
    pub game_phase: GamePhase,
    /// The game state.
    pub state: GameState,
    /// The set play in progress.
    pub set_play: SetPlay,
    /// Whether the first half is being played.
    pub first_half: bool,
    /// The team with the kick, if any.
    pub kicking_team: Option<u8>,
    /// Seconds left in the half (negative in overtime).
    pub secs_remaining: i16,
    /// A secondary clock (e.g. for set plays).
    pub secondary_time: i16,
    /// Both teams.
    pub teams: [TeamInfo; 2],
}

/// Reads little-endian fields from the fixed-size packet.
struct Reader<'a> {
    bytes: &'a [u8; PACKET_SIZE],
    at: usize,
}

impl Reader<'_> {
    fn u8(&mut self) -> u8 {
        self.at += 1;
        self.bytes[self.at - 1]
    }

    fn u16(&mut self) -> u16 {
        u16::from_le_bytes([self.u8(), self.u8()])
    }

    fn i16(&mut self) -> i16 {
        i16::from_le_bytes([self.u8(), self.u8()])
    }

    fn at_most(&mut self, field: &'static str, max: u8, expected: &'static str) -> Result<u8, PacketError> {
        let value = self.u8();
        if value > max {
            Err(PacketError::Invalid { field, value: value.into(), expected })
        } else {
            Ok(value)
        }
    }
}

impl GameControlData {
    /// Decodes and validates one UDP payload.
    pub fn parse(bytes: &[u8]) -> Result<Self, PacketError> {
        let bytes: &[u8; PACKET_SIZE] = bytes.try_into().map_err(|_| PacketError::WrongSize(bytes.len()))?;
        let header = [bytes[0], bytes[1], bytes[2], bytes[3]];
        if header != HEADER {
            return Err(PacketError::WrongHeader(header));
        }
        if bytes[4] != VERSION {
            return Err(PacketError::WrongVersion(bytes[4]));
        }
        let mut reader = Reader { bytes, at: 5 };
        let packet_number = reader.u8();
        let players_per_team = reader.at_most("playersPerTeam", MAX_PLAYERS as u8, "at most 20")?;
        let competition_phase = reader.at_most("competitionPhase", 1, "0 or 1")?;
        let competition_type = reader.at_most("competitionType", 1, "0 or 1")?;
        let game_phase = GamePhase::decode(reader.u8())?;
        let state = GameState::decode(reader.u8())?;
        let set_play = SetPlay::decode(reader.u8())?;
        let first_half = reader.at_most("firstHalf", 1, "0 or 1")? == 1;
        let kicking_team = Some(reader.u8()).filter(|&team| team != 255);
        let secs_remaining = reader.i16();
        let secondary_time = reader.i16();
        let teams = [Self::team(&mut reader)?, Self::team(&mut reader)?];
        debug_assert_eq!(reader.at, PACKET_SIZE);
        Ok(Self {
            packet_number,
            players_per_team,
            competition_phase,
            competition_type,
            game_phase,
            state,
            set_play,
            first_half,
            kicking_team,
            secs_remaining,
            secondary_time,
            teams,
        })
    }

    fn team(reader: &mut Reader) -> Result<TeamInfo, PacketError> {
        let team_number = reader.u8();
        let field_player_colour = reader.at_most("fieldPlayerColour", 9, "a colour 0..=9")?;
        let goalkeeper_colour = reader.at_most("goalkeeperColour", 9, "a colour 0..=9")?;
        let goalkeeper = reader.at_most("goalkeeper", MAX_PLAYERS as u8, "a player number 0..=20")?;
        let (score, penalty_shot, single_shots, message_budget) =
            (reader.u8(), reader.u8(), reader.u16(), reader.u16());
        let mut players = [RobotInfo { penalty: Penalty::None, secs_till_unpenalised: 0 }; MAX_PLAYERS];
        for player in &mut players {
            *player =
                RobotInfo { penalty: Penalty::decode(reader.u8())?, secs_till_unpenalised: reader.u8() };
        }
        Ok(TeamInfo {
            team_number,
            field_player_colour,
            goalkeeper_colour,
            goalkeeper,
            score,
            penalty_shot,
            single_shots,
            message_budget,
            players,
        })
    }

    /// Encodes the packet as the GameController sends it.
    pub fn to_bytes(&self) -> [u8; PACKET_SIZE] {
        let mut bytes = Vec::with_capacity(PACKET_SIZE);
        bytes.extend_from_slice(&HEADER);
        bytes.extend_from_slice(&[
            VERSION,
            self.packet_number,
            self.players_per_team,
            self.competition_phase,
            self.competition_type,
            self.game_phase.code(),
            self.state.code(),
            self.set_play.code(),
            u8::from(self.first_half),
            self.kicking_team.unwrap_or(255),
        ]);
        bytes.extend_from_slice(&self.secs_remaining.to_le_bytes());
        bytes.extend_from_slice(&self.secondary_time.to_le_bytes());
        for team in &self.teams {
            bytes.extend_from_slice(&[
                team.team_number,
                team.field_player_colour,
                team.goalkeeper_colour,
                team.goalkeeper,
                team.score,
                team.penalty_shot,
            ]);
            bytes.extend_from_slice(&team.single_shots.to_le_bytes());
            bytes.extend_from_slice(&team.message_budget.to_le_bytes());
            for player in &team.players {
                bytes.extend_from_slice(&[player.penalty.code(), player.secs_till_unpenalised]);
            }
        }
        debug_assert_eq!(bytes.len(), TEAMS_OFFSET + 2 * TEAM_SIZE);
        bytes.try_into().expect("the layout adds up to 118 bytes")
    }

    /// Our team's part, if this packet is about our team.
    pub fn team_info(&self, team_number: u8) -> Option<&TeamInfo> {
        self.teams.iter().find(|team| team.team_number == team_number)
    }
}

/// A robot put back on the field after a penalty that took it off: its pose is unknown.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Returned {
    /// The penalty that ended.
    pub penalty: Penalty,
}

/// How our player's penalty ended.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PenaltyEnd {
    /// The robot was put back: relocalise.
    Returned(Returned),
    /// The penalty ended sooner than the minimum: a mistake the referee revoked, the robot was not
    /// moved.
    Revoked {
        /// The penalty.
        penalty: Penalty,
        /// How long it lasted, seconds.
        seconds: f64,
    },
}

/// Follows our player's penalty across packets and reports when it returns from a penalty that moved it.
#[derive(Clone, Debug)]
pub struct PenaltyWatch {
    team_number: u8,
    player_number: u8,
    min_penalty_s: f64,
    last: Option<Penalty>,
    since: Option<f64>,
}

impl PenaltyWatch {
    /// Watches player `player_number` (1-based) of team `team_number`; a penalty that ends within
    /// `min_penalty_s` seconds counts as revoked.
    pub fn new(team_number: u8, player_number: u8, min_penalty_s: f64) -> Self {
        Self { team_number, player_number, min_penalty_s, last: None, since: None }
    }

    /// Our player's penalty in the last packet about our team, if any.
    pub fn penalty(&self) -> Option<Penalty> {
        self.last
    }

    /// Takes one packet received at `now_s` seconds (any monotonic clock); returns `Some` when our
    /// player's penalty that moved it has just ended: returned, or revoked when it lasted less than
    /// the minimum. A penalty first seen in the watch's first packet counts from then. Packets for
    /// other teams change nothing.
    pub fn update(&mut self, packet: &GameControlData, now_s: f64) -> Option<PenaltyEnd> {
        let penalty = packet.team_info(self.team_number)?.player(self.player_number)?.penalty;
        let previous = self.last.replace(penalty);
        if penalty.moves_robot() {
            if !previous.is_some_and(Penalty::moves_robot) {
                self.since = Some(now_s);
            }
            return None;
        }
        let since = self.since.take();
        match previous {
            Some(previous) if previous.moves_robot() && penalty == Penalty::None => {
                let seconds = now_s - since.unwrap_or(now_s);
                Some(if seconds < self.min_penalty_s {
                    PenaltyEnd::Revoked { penalty: previous, seconds }
                } else {
                    PenaltyEnd::Returned(Returned { penalty: previous })
                })
            }
            _ => None,
        }
    }
}

/// How long the followed GameController may be silent before another source, or a packet number
/// that went backwards (a restarted GameController counts from 0), is accepted. It sends at 2 Hz.
pub const SILENCE_BEFORE_SWITCHING_S: f64 = 2.0;

/// Why a well-formed packet was not used.
#[derive(Clone, Copy, Debug, Error, PartialEq, Eq)]
pub enum Ignored {
    /// Another GameController is being followed and is still sending.
    #[error("from {0}, while another GameController is being followed")]
    OtherSource(IpAddr),
    /// A duplicate, or an old packet replayed: its number is not ahead of the last one used.
    #[error("packet number {got} is not newer than {last}")]
    NotNewer {
        /// The last packet number used.
        last: u8,
        /// This packet's number.
        got: u8,
    },
}

/// Lets through packets from one GameController at a time, in order, so that a second
/// GameController on the network, duplicates and replayed old packets cannot fake a penalty or its end.
/// Packet numbers wrap at 256: a number up to 127 ahead of the last one is newer.
#[derive(Clone, Debug, Default)]
pub struct PacketOrder {
    /// The followed source, its last packet number, and when it was heard (seconds, caller's clock).
    followed: Option<(IpAddr, u8, f64)>,
}

impl PacketOrder {
    /// Whether to use a packet numbered `packet_number` from `source`, received at `now_s`.
    pub fn accept(&mut self, source: IpAddr, packet_number: u8, now_s: f64) -> Result<(), Ignored> {
        if let Some((followed, last, heard)) = self.followed {
            let silent = now_s - heard > SILENCE_BEFORE_SWITCHING_S;
            if !silent {
                if source != followed {
                    return Err(Ignored::OtherSource(source));
                }
                if !(1..128).contains(&packet_number.wrapping_sub(last)) {
                    return Err(Ignored::NotNewer { last, got: packet_number });
                }
            }
        }
        self.followed = Some((source, packet_number, now_s));
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const GC: IpAddr = IpAddr::V4(std::net::Ipv4Addr::new(10, 0, 0, 1));
    const OTHER: IpAddr = IpAddr::V4(std::net::Ipv4Addr::new(10, 0, 0, 2));

    #[test]
    fn packets_are_used_in_order_from_one_gamecontroller() {
        let mut order = PacketOrder::default();
        assert_eq!(order.accept(GC, 10, 0.0), Ok(()));
        assert_eq!(order.accept(GC, 11, 0.5), Ok(()));
        assert_eq!(order.accept(GC, 11, 0.6), Err(Ignored::NotNewer { last: 11, got: 11 }));
        assert_eq!(order.accept(GC, 5, 0.7), Err(Ignored::NotNewer { last: 11, got: 5 }));
        assert_eq!(order.accept(OTHER, 12, 0.8), Err(Ignored::OtherSource(OTHER)));
        assert_eq!(order.accept(GC, 13, 1.0), Ok(()), "a lost packet is no reason to stop");
    }

    #[test]
    fn numbers_wrap_and_a_silent_gamecontroller_can_be_replaced() {
        let mut order = PacketOrder::default();
        order.accept(GC, 254, 0.0).unwrap();
        assert_eq!(order.accept(GC, 1, 0.5), Ok(()), "255 → 0 → 1");
        // A restarted GameController counts from 0 again; another one takes over after silence.
        assert_eq!(order.accept(GC, 0, 3.0), Ok(()));
        assert_eq!(order.accept(OTHER, 0, 5.5), Ok(()));
        assert_eq!(order.accept(GC, 1, 5.6), Err(Ignored::OtherSource(GC)));
    }

    fn team(number: u8) -> TeamInfo {
        TeamInfo {
            team_number: number,
            field_player_colour: 0,
            goalkeeper_colour: 1,
            goalkeeper: 1,
            score: 0,
            penalty_shot: 0,
            single_shots: 0,
            message_budget: 1200,
            players: [RobotInfo { penalty: Penalty::None, secs_till_unpenalised: 0 }; MAX_PLAYERS],
        }
    }

    fn packet(penalty_of_our_player_2: Penalty) -> GameControlData {
        let mut ours = team(5);
        ours.players[1].penalty = penalty_of_our_player_2;
        GameControlData {
            packet_number: 7,
            players_per_team: 7,
            competition_phase: 0,
            competition_type: 0,
            game_phase: GamePhase::Normal,
            state: GameState::Playing,
            set_play: SetPlay::None,
            first_half: true,
            kicking_team: Some(5),
            secs_remaining: 421,
            secondary_time: -3,
            teams: [ours, team(12)],
        }
    }

    #[test]
    fn a_packet_survives_encoding_and_matches_the_c_layout() {
        let packet = packet(Penalty::RequestForPickup);
        let bytes = packet.to_bytes();
        assert_eq!(&bytes[..5], b"RGme\x12");
        assert_eq!(i16::from_le_bytes([bytes[14], bytes[15]]), 421);
        assert_eq!(bytes[TEAMS_OFFSET], 5, "teams[0].teamNumber");
        assert_eq!(u16::from_le_bytes([bytes[TEAMS_OFFSET + 8], bytes[TEAMS_OFFSET + 9]]), 1200);
        assert_eq!(bytes[TEAMS_OFFSET + 10 + 2], 7, "teams[0].players[1].penalty");
        assert_eq!(bytes[TEAMS_OFFSET + TEAM_SIZE], 12, "teams[1].teamNumber");
        assert_eq!(GameControlData::parse(&bytes).unwrap(), packet);
    }

    #[test]
    fn bad_packets_name_what_is_wrong() {
        let good = packet(Penalty::None).to_bytes();
        assert_eq!(GameControlData::parse(&good[..117]), Err(PacketError::WrongSize(117)));
        let mut header = good;
        header[..4].copy_from_slice(b"RGrt");
        assert_eq!(GameControlData::parse(&header), Err(PacketError::WrongHeader(*b"RGrt")));
        let mut version = good;
        version[4] = 17;
        assert_eq!(GameControlData::parse(&version), Err(PacketError::WrongVersion(17)));
        let mut state = good;
        state[10] = 9;
        assert!(matches!(
            GameControlData::parse(&state),
            Err(PacketError::Invalid { field: "state", value: 9, .. })
        ));
        let mut penalty = good;
        penalty[TEAMS_OFFSET + TEAM_SIZE + 10 + 2 * 4] = 12;
        let error = GameControlData::parse(&penalty).unwrap_err();
        assert!(matches!(error, PacketError::Invalid { field: "penalty", value: 12, .. }));
        assert!(error.to_string().contains("one of 0 1 2"), "{error}");
    }

    #[test]
    fn returning_from_a_penalty_that_moved_the_robot_is_a_kidnap() {
        let mut watch = PenaltyWatch::new(5, 2, 2.0);
        assert_eq!(watch.update(&packet(Penalty::None), 0.0), None);
        assert_eq!(watch.update(&packet(Penalty::PlayerPushing), 0.5), None);
        assert_eq!(watch.update(&packet(Penalty::PlayerPushing), 1.0), None);
        assert_eq!(
            watch.update(&packet(Penalty::None), 45.5),
            Some(PenaltyEnd::Returned(Returned { penalty: Penalty::PlayerPushing }))
        );
        assert_eq!(watch.update(&packet(Penalty::None), 46.0), None, "reported once");
        assert_eq!(watch.penalty(), Some(Penalty::None));
    }

    #[test]
    fn a_penalty_shorter_than_the_minimum_was_revoked() {
        let mut watch = PenaltyWatch::new(5, 2, 2.0);
        watch.update(&packet(Penalty::None), 0.0);
        watch.update(&packet(Penalty::RequestForPickup), 10.0);
        // Another moving penalty in between does not restart the clock.
        watch.update(&packet(Penalty::PlayerPushing), 10.5);
        assert_eq!(
            watch.update(&packet(Penalty::None), 11.0),
            Some(PenaltyEnd::Revoked { penalty: Penalty::PlayerPushing, seconds: 1.0 })
        );
        watch.update(&packet(Penalty::PlayerPushing), 20.0);
        assert!(matches!(watch.update(&packet(Penalty::None), 22.0), Some(PenaltyEnd::Returned(_))));
    }

    #[test]
    fn in_place_penalties_and_other_teams_do_not_trigger() {
        let mut watch = PenaltyWatch::new(5, 2, 2.0);
        watch.update(&packet(Penalty::IllegalMotionInSet), 0.0);
        assert_eq!(watch.update(&packet(Penalty::None), 30.0), None);
        watch.update(&packet(Penalty::IllegalMotionInStandby), 40.0);
        assert_eq!(watch.update(&packet(Penalty::None), 70.0), None);
        let mut other = PenaltyWatch::new(33, 2, 2.0);
        other.update(&packet(Penalty::LeavingTheField), 0.0);
        assert_eq!(other.update(&packet(Penalty::None), 30.0), None);
        assert_eq!(other.penalty(), None);
        let mut no_slot = PenaltyWatch::new(5, 21, 2.0);
        assert_eq!(no_slot.update(&packet(Penalty::None), 0.0), None);
    }

    proptest! {
        #[test]
        fn any_bytes_decode_to_a_valid_packet_or_an_error(bytes in prop::collection::vec(any::<u8>(), 0..140)) {
            if let Ok(packet) = GameControlData::parse(&bytes) {
                prop_assert_eq!(packet.to_bytes().to_vec(), bytes);
            }
        }

        #[test]
        fn a_changed_byte_decodes_to_exactly_those_bytes_or_an_error(at in 0..PACKET_SIZE, value in any::<u8>()) {
            let mut bytes = packet(Penalty::None).to_bytes();
            bytes[at] = value;
            if let Ok(packet) = GameControlData::parse(&bytes) {
                prop_assert_eq!(packet.to_bytes(), bytes);
            }
        }
    }
}
