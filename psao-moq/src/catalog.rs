//! The `catalog` track (spec/moq.md 3): what `WELCOME` says in a direct
//! session, said once for every subscriber of a broadcast; and the
//! `digest` track's frames (spec/moq.md 5).

use bytes::Bytes;
use psao_proto::SessionError;
use psao_proto::control::{Control, Welcome, kind};

/// Bytes before a control message's body: its `length` (u16) and `type`.
const CONTROL_PREFIX: usize = 3;

/// Track names of a broadcast (spec/moq.md 2).
pub mod track {
    /// The catalog: one `WELCOME` body.
    pub const CATALOG: &str = "catalog";
    /// The PSAO frames.
    pub const FRAMES: &str = "frames";
    /// Digests of the mirror after some frames.
    pub const DIGEST: &str = "digest";
}

/// The reference publisher's broadcast name for a scene: `psao/` and the
/// scene name, with `/` in it replaced by `_` (spec/moq.md 2).
pub fn broadcast_name(scene: &str) -> String {
    let scene = if scene.is_empty() { "scene" } else { scene };
    format!("psao/{}", scene.replace('/', "_"))
}

/// Encodes a catalog frame: the body of `WELCOME` for `welcome`, whose
/// `culling` is cleared (a relay serves no camera, spec/moq.md 3).
pub fn encode_catalog(welcome: &Welcome) -> Bytes {
    let mut w = welcome.clone();
    w.culling = false;
    let mut b = Control::Welcome(w).to_bytes();
    let _ = b.split_to(CONTROL_PREFIX);
    b.freeze()
}

/// Parses a catalog frame; a malformed one, or one whose version is not
/// psao's, or one that sets `culling`, is an error naming the field.
pub fn decode_catalog(body: &[u8]) -> Result<Welcome, SessionError> {
    match Control::decode(kind::WELCOME, body)? {
        Control::Welcome(w) if w.culling => Err(SessionError::malformed(
            "catalog",
            "flags.culling is set (a broadcast is not culled)",
        )),
        Control::Welcome(w) => Ok(w),
        _ => Err(SessionError::malformed("catalog", "not a WELCOME body")),
    }
}

/// Encodes a `digest` track frame: the 8-byte body of `DIGEST`.
pub fn encode_digest(sequence: u32, digest: u32) -> Bytes {
    let mut b = Control::Digest { sequence, digest }.to_bytes();
    let _ = b.split_to(CONTROL_PREFIX);
    b.freeze()
}

/// Parses a `digest` track frame into `(sequence, digest)`.
pub fn decode_digest(body: &[u8]) -> Result<(u32, u32), SessionError> {
    match Control::decode(kind::DIGEST, body)? {
        Control::Digest { sequence, digest } => Ok((sequence, digest)),
        _ => Err(SessionError::malformed("digest", "not a DIGEST body")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn welcome() -> Welcome {
        Welcome {
            version: 1,
            compression: 2,
            point_format: 1,
            max_frame_bytes: 1 << 20,
            max_payload_bytes: 4 << 20,
            frame_rate: 60,
            culling: true,
            overflow: true,
            digest: true,
            scene: "default".into(),
        }
    }

    #[test]
    fn a_catalog_is_a_welcome_body_without_culling() {
        let body = encode_catalog(&welcome());
        // 16 fixed bytes and the name (spec/session.md 3.2).
        assert_eq!(body.len(), 16 + 7);
        assert_eq!(body[14], 0b110, "flags: overflow and digest, no culling");
        let back = decode_catalog(&body).unwrap();
        assert_eq!(
            back,
            Welcome {
                culling: false,
                ..welcome()
            }
        );
    }

    #[test]
    fn a_catalog_with_culling_or_cut_short_is_refused() {
        let mut body = encode_catalog(&welcome()).to_vec();
        body[14] |= 1;
        assert!(decode_catalog(&body).is_err());
        let body = encode_catalog(&welcome());
        assert!(decode_catalog(&body[..10]).is_err());
    }

    #[test]
    fn digests_round_trip_as_eight_bytes() {
        let b = encode_digest(7, 0xdead_beef);
        assert_eq!(&b[..], &[7, 0, 0, 0, 0xef, 0xbe, 0xad, 0xde]);
        assert_eq!(decode_digest(&b).unwrap(), (7, 0xdead_beef));
        assert!(decode_digest(&b[..7]).is_err());
    }

    #[test]
    fn broadcast_names_hold_no_extra_slash() {
        assert_eq!(broadcast_name("default"), "psao/default");
        assert_eq!(broadcast_name("a/b"), "psao/a_b");
        assert_eq!(broadcast_name(""), "psao/scene");
    }
}
