//! [`MaterialEntry`]: a runtime parameter type attached to a material by name, written flat in
//! a scene file — `(material: "honey", diffusivity: 0.01, ...)` — without a hand-written mirror
//! of the parameter type's fields.
//!
//! serde's `flatten` cannot do this: it cannot reject unknown fields and it buffers the values,
//! so errors lose their position in the file. The (de)serialisers here stream instead: the
//! `material` field is taken out of the map as it passes and every other entry goes straight to
//! the parameter type's own `Deserialize`, with its defaults, its `deny_unknown_fields` and the
//! file position of every error.
use std::fmt;
use std::marker::PhantomData;
use std::ops::{Deref, DerefMut};

use serde::de::value::{MapAccessDeserializer, StringDeserializer};
use serde::de::{self, DeserializeSeed, IntoDeserializer, MapAccess, Visitor};
use serde::ser::{self, Impossible, SerializeStruct};
use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// The key that names the material.
const MATERIAL: &str = "material";

/// A field or variant name, read as an identifier (RON refuses to read one as a string).
#[derive(Debug)]
pub struct Identifier(pub String);

impl<'de> Deserialize<'de> for Identifier {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct IdVisitor;
        impl Visitor<'_> for IdVisitor {
            type Value = Identifier;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("an identifier")
            }
            fn visit_str<E: de::Error>(self, v: &str) -> Result<Identifier, E> {
                Ok(Identifier(v.to_owned()))
            }
        }
        deserializer.deserialize_identifier(IdVisitor)
    }
}

/// Parameters `params` of the material named `material`; the scene file writes the material's
/// name next to the parameters' own fields. Dereferences to the parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct MaterialEntry<T> {
    /// Name of a material in the scene's `materials`.
    pub material: String,
    /// The runtime parameters.
    pub params: T,
}

impl<T> MaterialEntry<T> {
    /// Parameters `params` for the material `material`.
    pub fn new(material: impl Into<String>, params: T) -> Self {
        Self {
            material: material.into(),
            params,
        }
    }
}

impl<T> Deref for MaterialEntry<T> {
    type Target = T;
    fn deref(&self) -> &T {
        &self.params
    }
}

impl<T> DerefMut for MaterialEntry<T> {
    fn deref_mut(&mut self) -> &mut T {
        &mut self.params
    }
}

/// The last path segment of `T`'s type name, e.g. `ThermalMaterial` (a RON file may write the
/// struct name before the parentheses).
fn short_name<T>() -> &'static str {
    let full = std::any::type_name::<T>();
    full.rsplit("::").next().unwrap_or(full)
}

impl<'de, T: Deserialize<'de>> Deserialize<'de> for MaterialEntry<T> {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        deserializer.deserialize_struct(short_name::<T>(), &[], EntryVisitor(PhantomData))
    }
}

struct EntryVisitor<T>(PhantomData<T>);

impl<'de, T: Deserialize<'de>> Visitor<'de> for EntryVisitor<T> {
    type Value = MaterialEntry<T>;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        write!(
            f,
            "a `material` name and the fields of {}",
            short_name::<T>()
        )
    }

    fn visit_map<A: MapAccess<'de>>(self, map: A) -> Result<Self::Value, A::Error> {
        let mut material = None;
        let params = T::deserialize(MapAccessDeserializer::new(WithoutMaterial {
            map,
            material: &mut material,
        }))?;
        let material = material.ok_or_else(|| de::Error::missing_field(MATERIAL))?;
        Ok(MaterialEntry { material, params })
    }
}

/// The entries of a map except `material`, which is stored as it passes.
struct WithoutMaterial<'a, A> {
    map: A,
    material: &'a mut Option<String>,
}

impl<'de, A: MapAccess<'de>> MapAccess<'de> for WithoutMaterial<'_, A> {
    type Error = A::Error;

    fn next_key_seed<K: DeserializeSeed<'de>>(
        &mut self,
        seed: K,
    ) -> Result<Option<K::Value>, A::Error> {
        while let Some(Identifier(key)) = self.map.next_key()? {
            if key != MATERIAL {
                let key: StringDeserializer<A::Error> = key.into_deserializer();
                return seed.deserialize(key).map(Some);
            }
            if self.material.is_some() {
                return Err(de::Error::duplicate_field(MATERIAL));
            }
            *self.material = Some(self.map.next_value()?);
        }
        Ok(None)
    }

    fn next_value_seed<V: DeserializeSeed<'de>>(&mut self, seed: V) -> Result<V::Value, A::Error> {
        self.map.next_value_seed(seed)
    }
}

impl<T: Serialize> Serialize for MaterialEntry<T> {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        self.params.serialize(WithMaterial {
            inner: serializer,
            material: &self.material,
        })
    }
}

/// A serialiser that writes `material` as the first field of the struct it is given.
struct WithMaterial<'a, S> {
    inner: S,
    material: &'a str,
}

/// Methods of [`WithMaterial`] for anything but a struct: an error.
macro_rules! not_a_struct {
    ($($name:ident($($arg:ty),*) -> $ret:ty;)*) => {$(
        fn $name(self, $(_: $arg),*) -> Result<$ret, S::Error> {
            Err(ser::Error::custom(
                "the parameters of a material entry must serialise as a struct",
            ))
        }
    )*};
}

impl<S: Serializer> Serializer for WithMaterial<'_, S> {
    type Ok = S::Ok;
    type Error = S::Error;
    type SerializeSeq = Impossible<S::Ok, S::Error>;
    type SerializeTuple = Impossible<S::Ok, S::Error>;
    type SerializeTupleStruct = Impossible<S::Ok, S::Error>;
    type SerializeTupleVariant = Impossible<S::Ok, S::Error>;
    type SerializeMap = Impossible<S::Ok, S::Error>;
    type SerializeStruct = S::SerializeStruct;
    type SerializeStructVariant = Impossible<S::Ok, S::Error>;

    fn serialize_struct(
        self,
        name: &'static str,
        len: usize,
    ) -> Result<S::SerializeStruct, S::Error> {
        let mut s = self.inner.serialize_struct(name, len + 1)?;
        s.serialize_field(MATERIAL, self.material)?;
        Ok(s)
    }

    fn serialize_some<V: Serialize + ?Sized>(self, _: &V) -> Result<S::Ok, S::Error> {
        Err(ser::Error::custom(
            "the parameters of a material entry must serialise as a struct",
        ))
    }

    fn serialize_newtype_struct<V: Serialize + ?Sized>(
        self,
        _: &'static str,
        _: &V,
    ) -> Result<S::Ok, S::Error> {
        Err(ser::Error::custom(
            "the parameters of a material entry must serialise as a struct",
        ))
    }

    fn serialize_newtype_variant<V: Serialize + ?Sized>(
        self,
        _: &'static str,
        _: u32,
        _: &'static str,
        _: &V,
    ) -> Result<S::Ok, S::Error> {
        Err(ser::Error::custom(
            "the parameters of a material entry must serialise as a struct",
        ))
    }

    not_a_struct! {
        serialize_bool(bool) -> S::Ok;
        serialize_i8(i8) -> S::Ok;
        serialize_i16(i16) -> S::Ok;
        serialize_i32(i32) -> S::Ok;
        serialize_i64(i64) -> S::Ok;
        serialize_u8(u8) -> S::Ok;
        serialize_u16(u16) -> S::Ok;
        serialize_u32(u32) -> S::Ok;
        serialize_u64(u64) -> S::Ok;
        serialize_f32(f32) -> S::Ok;
        serialize_f64(f64) -> S::Ok;
        serialize_char(char) -> S::Ok;
        serialize_str(&str) -> S::Ok;
        serialize_bytes(&[u8]) -> S::Ok;
        serialize_none() -> S::Ok;
        serialize_unit() -> S::Ok;
        serialize_unit_struct(&'static str) -> S::Ok;
        serialize_unit_variant(&'static str, u32, &'static str) -> S::Ok;
        serialize_seq(Option<usize>) -> Self::SerializeSeq;
        serialize_tuple(usize) -> Self::SerializeTuple;
        serialize_tuple_struct(&'static str, usize) -> Self::SerializeTupleStruct;
        serialize_tuple_variant(&'static str, u32, &'static str, usize) -> Self::SerializeTupleVariant;
        serialize_map(Option<usize>) -> Self::SerializeMap;
        serialize_struct_variant(&'static str, u32, &'static str, usize) -> Self::SerializeStructVariant;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
    #[serde(deny_unknown_fields)]
    struct Params {
        a: f64,
        #[serde(default)]
        b: Option<u32>,
    }

    fn parse(text: &str) -> Result<MaterialEntry<Params>, ron::error::SpannedError> {
        ron::from_str(text)
    }

    #[test]
    fn material_anywhere_defaults_apply() {
        let want = MaterialEntry::new("honey", Params { a: 1.5, b: None });
        assert_eq!(parse(r#"(material: "honey", a: 1.5)"#).unwrap(), want);
        assert_eq!(parse(r#"(a: 1.5, material: "honey")"#).unwrap(), want);
        assert_eq!(parse(r#"Params(a: 1.5, material: "honey")"#).unwrap(), want);
        assert_eq!(parse(r#"(material:"x",a:2,b:Some(3))"#).unwrap().b, Some(3));
    }

    #[test]
    fn errors_keep_the_field_and_position() {
        let e = parse("(material: \"honey\",\n a: 1.5,\n c: 2)").unwrap_err();
        assert!(e.to_string().contains("`c`"), "{e}");
        assert_eq!(e.span.start.line, 3, "{e}");
        let e = parse("(material: \"honey\",\n a: true)").unwrap_err();
        assert_eq!(e.span.start.line, 2, "{e}");
        let e = parse("(a: 1.5)").unwrap_err();
        assert!(e.to_string().contains("`material`"), "{e}");
        let e = parse(r#"(material: "x", material: "y", a: 1)"#).unwrap_err();
        assert!(e.to_string().contains("duplicate"), "{e}");
        let e = parse(r#"(material: "x")"#).unwrap_err();
        assert!(e.to_string().contains("`a`"), "{e}");
    }

    #[test]
    fn round_trip() {
        let entry = MaterialEntry::new(
            "milk",
            Params {
                a: -2.0,
                b: Some(7),
            },
        );
        let text = ron::to_string(&entry).unwrap();
        assert!(text.starts_with("(material:"), "{text}");
        assert_eq!(parse(&text).unwrap(), entry);
    }
}
