//! Floats in the JSON form, non-finite ones included.
//!
//! JSON has numbers but no NaN or infinity. Finite values are written as
//! numbers (unchanged); NaN, +∞ and −∞ as the strings `"NaN"`, `"Infinity"`
//! and `"-Infinity"` (the spellings JavaScript and Python use), so every
//! value reads back as it was written. NaN payload bits are not kept. A
//! `null` where a float belongs reads as NaN: that is how smokenav wrote
//! non-finite values before. (`null` inside `ranges` still means "no range".)
//!
//! Used as `#[serde(with = "float")]` and its container variants.

use serde::de::{self, Deserializer, Visitor};
use serde::ser::Serializer;
use serde::{Deserialize, Serialize};

/// Spelling of NaN.
pub const NAN: &str = "NaN";
/// Spelling of +∞.
pub const INFINITY: &str = "Infinity";
/// Spelling of −∞.
pub const NEG_INFINITY: &str = "-Infinity";

/// `f32` or `f64`.
pub trait Float: Copy {
    /// Converts a parsed JSON number.
    fn from_f64(v: f64) -> Self;
    /// Writes a finite value as a JSON number.
    fn serialize_number<S: Serializer>(self, s: S) -> Result<S::Ok, S::Error>;
    /// As `f64` (exact), for classification.
    fn to_f64(self) -> f64;
}

impl Float for f32 {
    fn from_f64(v: f64) -> Self {
        v as f32
    }
    fn serialize_number<S: Serializer>(self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_f32(self)
    }
    fn to_f64(self) -> f64 {
        f64::from(self)
    }
}

impl Float for f64 {
    fn from_f64(v: f64) -> Self {
        v
    }
    fn serialize_number<S: Serializer>(self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_f64(self)
    }
    fn to_f64(self) -> f64 {
        self
    }
}

/// A float that serialises as described in the module docs.
#[derive(Debug, Clone, Copy)]
pub struct Json<F>(pub F);

impl<F: Float> Serialize for Json<F> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let v = self.0.to_f64();
        if v.is_finite() {
            self.0.serialize_number(s)
        } else if v.is_nan() {
            s.serialize_str(NAN)
        } else if v > 0.0 {
            s.serialize_str(INFINITY)
        } else {
            s.serialize_str(NEG_INFINITY)
        }
    }
}

struct FloatVisitor<F>(core::marker::PhantomData<F>);

impl<F: Float> Visitor<'_> for FloatVisitor<F> {
    type Value = F;

    fn expecting(&self, f: &mut core::fmt::Formatter) -> core::fmt::Result {
        write!(
            f,
            "a number, \"{NAN}\", \"{INFINITY}\" or \"{NEG_INFINITY}\""
        )
    }

    fn visit_f64<E: de::Error>(self, v: f64) -> Result<F, E> {
        Ok(F::from_f64(v))
    }

    fn visit_u64<E: de::Error>(self, v: u64) -> Result<F, E> {
        Ok(F::from_f64(v as f64))
    }

    fn visit_i64<E: de::Error>(self, v: i64) -> Result<F, E> {
        Ok(F::from_f64(v as f64))
    }

    fn visit_str<E: de::Error>(self, v: &str) -> Result<F, E> {
        match v {
            NAN => Ok(F::from_f64(f64::NAN)),
            INFINITY => Ok(F::from_f64(f64::INFINITY)),
            NEG_INFINITY => Ok(F::from_f64(f64::NEG_INFINITY)),
            _ => Err(E::invalid_value(de::Unexpected::Str(v), &self)),
        }
    }

    fn visit_unit<E: de::Error>(self) -> Result<F, E> {
        Ok(F::from_f64(f64::NAN))
    }

    fn visit_none<E: de::Error>(self) -> Result<F, E> {
        Ok(F::from_f64(f64::NAN))
    }
}

impl<'de, F: Float> Deserialize<'de> for Json<F> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_any(FloatVisitor(core::marker::PhantomData))
            .map(Json)
    }
}

/// One float field.
pub fn serialize<F: Float, S: Serializer>(v: &F, s: S) -> Result<S::Ok, S::Error> {
    Json(*v).serialize(s)
}

/// One float field.
pub fn deserialize<'de, F: Float, D: Deserializer<'de>>(d: D) -> Result<F, D::Error> {
    Json::deserialize(d).map(|j| j.0)
}

/// `Vec<F>`.
pub mod vec {
    use super::{Float, Json};
    use serde::{Deserialize, Deserializer, Serializer};

    /// Writes every element as a [`Json`] float.
    pub fn serialize<F: Float, S: Serializer>(v: &[F], s: S) -> Result<S::Ok, S::Error> {
        s.collect_seq(v.iter().map(|x| Json(*x)))
    }

    /// Reads a sequence of [`Json`] floats.
    pub fn deserialize<'de, F: Float, D: Deserializer<'de>>(d: D) -> Result<Vec<F>, D::Error> {
        Ok(Vec::<Json<F>>::deserialize(d)?
            .into_iter()
            .map(|j| j.0)
            .collect())
    }
}

/// `Vec<Option<F>>`: `null` is `None`, everything else a [`Json`] float.
pub mod vec_option {
    use super::{Float, Json};
    use serde::{Deserialize, Deserializer, Serializer};

    /// Writes `None` as `null`, values as [`Json`] floats.
    pub fn serialize<F: Float, S: Serializer>(v: &[Option<F>], s: S) -> Result<S::Ok, S::Error> {
        s.collect_seq(v.iter().map(|x| x.map(Json)))
    }

    /// Reads `null` as `None`, values as [`Json`] floats.
    pub fn deserialize<'de, F: Float, D: Deserializer<'de>>(
        d: D,
    ) -> Result<Vec<Option<F>>, D::Error> {
        Ok(Vec::<Option<Json<F>>>::deserialize(d)?
            .into_iter()
            .map(|j| j.map(|j| j.0))
            .collect())
    }
}

/// `Option<Vec<F>>`, for optional arrays (`intensities`).
pub mod option_vec {
    use super::{Float, Json};
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    /// Writes `None` as `null`, a vector as [`Json`] floats.
    pub fn serialize<F: Float, S: Serializer>(v: &Option<Vec<F>>, s: S) -> Result<S::Ok, S::Error> {
        v.as_ref()
            .map(|v| v.iter().map(|x| Json(*x)).collect::<Vec<_>>())
            .serialize(s)
    }

    /// Reads `null` as `None`, an array as [`Json`] floats.
    pub fn deserialize<'de, F: Float, D: Deserializer<'de>>(
        d: D,
    ) -> Result<Option<Vec<F>>, D::Error> {
        Ok(Option::<Vec<Json<F>>>::deserialize(d)?.map(|v| v.into_iter().map(|j| j.0).collect()))
    }
}

/// `Option<F>`: `null` (or absent, with `#[serde(default)]`) is `None`.
pub mod option {
    use super::{Float, Json};
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    /// Writes `None` as `null`, a value as a [`Json`] float.
    pub fn serialize<F: Float, S: Serializer>(v: &Option<F>, s: S) -> Result<S::Ok, S::Error> {
        v.map(Json).serialize(s)
    }

    /// Reads `null` as `None`, a value as a [`Json`] float.
    pub fn deserialize<'de, F: Float, D: Deserializer<'de>>(d: D) -> Result<Option<F>, D::Error> {
        Ok(Option::<Json<F>>::deserialize(d)?.map(|j| j.0))
    }
}

/// `[F; N]`.
pub mod array {
    use super::{Float, Json};
    use serde::de::Error;
    use serde::{Deserialize, Deserializer, Serializer};

    /// Writes every element as a [`Json`] float.
    pub fn serialize<F: Float, S: Serializer, const N: usize>(
        v: &[F; N],
        s: S,
    ) -> Result<S::Ok, S::Error> {
        s.collect_seq(v.iter().map(|x| Json(*x)))
    }

    /// Reads exactly `N` [`Json`] floats.
    pub fn deserialize<'de, F: Float, D: Deserializer<'de>, const N: usize>(
        d: D,
    ) -> Result<[F; N], D::Error> {
        let v = Vec::<Json<F>>::deserialize(d)?;
        let len = v.len();
        let v: Vec<F> = v.into_iter().map(|j| j.0).collect();
        v.try_into()
            .map_err(|_| D::Error::invalid_length(len, &format!("{N} numbers").as_str()))
    }
}
