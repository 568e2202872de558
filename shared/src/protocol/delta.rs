//! Batches whose items carry a ray id, with the ids delta-coded on the wire: each item starts
//! with the difference to the previous item's id (the first: to 0) as a zigzag varint, so a
//! batch sorted by id spends one byte per id (differences −64 ..= 63) instead of two. Any order
//! decodes; a sum off the u16 range is malformed.
//!
//! Used with `#[serde(with = "delta")]` on a `heapless::Vec` of a [`Keyed`] item.

use core::marker::PhantomData;
use serde::de::{DeserializeOwned, Error as _, SeqAccess, Visitor};
use serde::ser::SerializeSeq;
use serde::{Deserializer, Serialize, Serializer};

/// An item with a ray id and the rest of its wire form.
pub trait Keyed: Sized {
    /// Everything but the id, as it goes on the wire.
    type Rest: Serialize + DeserializeOwned;
    /// The ray id.
    fn id(&self) -> u16;
    /// Everything but the id.
    fn rest(&self) -> Self::Rest;
    /// The item of an id and the rest.
    fn join(id: u16, rest: Self::Rest) -> Self;
}

/// Write the batch: its length, then per item the id difference and the rest.
pub fn serialize<T: Keyed, const N: usize, S: Serializer>(
    items: &heapless::Vec<T, N>,
    s: S,
) -> Result<S::Ok, S::Error> {
    let mut seq = s.serialize_seq(Some(items.len()))?;
    let mut previous = 0i32;
    for item in items {
        let id = i32::from(item.id());
        seq.serialize_element(&(id - previous, item.rest()))?;
        previous = id;
    }
    seq.end()
}

/// Read a batch of at most `N` items.
pub fn deserialize<'de, T: Keyed, const N: usize, D: Deserializer<'de>>(
    d: D,
) -> Result<heapless::Vec<T, N>, D::Error> {
    struct Batch<T, const N: usize>(PhantomData<T>);

    impl<'de, T: Keyed, const N: usize> Visitor<'de> for Batch<T, N> {
        type Value = heapless::Vec<T, N>;

        fn expecting(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
            write!(f, "at most {N} items with delta-coded ray ids")
        }

        fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
            let mut items = heapless::Vec::new();
            let mut previous = 0i32;
            while let Some((delta, rest)) = seq.next_element::<(i32, T::Rest)>()? {
                let id = previous
                    .checked_add(delta)
                    .and_then(|id| u16::try_from(id).ok())
                    .ok_or_else(|| A::Error::custom("ray id off the u16 range"))?;
                items
                    .push(T::join(id, rest))
                    .map_err(|_| A::Error::custom("more items than the batch holds"))?;
                previous = i32::from(id);
            }
            Ok(items)
        }
    }

    d.deserialize_seq(Batch::<T, N>(PhantomData))
}
