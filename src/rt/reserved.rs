//! [`Reserved`]: a `Vec` whose capacity is fixed when it is built, and
//! which a clone keeps.
//!
//! The real-time paths size their lists once and then push only while
//! `len() < capacity()`, so that a step never allocates. A derived
//! `Clone` of a plain `Vec` allocates only what the vector holds at the
//! time: a clone of a wire made before its contacts came would have had
//! room for none of them, and dropped them (or, where a list is filled
//! without that check, allocated in the step). Wrapping such a list in
//! [`Reserved`] makes every clone a full second copy with the same room.

use std::ops::{Deref, DerefMut};

/// A `Vec` with its capacity reserved at construction; [`Clone`] reserves
/// the same capacity. It dereferences to the `Vec`, so the usual methods
/// apply; pushing past the capacity would allocate, so the real-time code
/// checks `len() < capacity()` first.
#[derive(Debug, Default, PartialEq)]
pub struct Reserved<T>(Vec<T>);

impl<T> Reserved<T> {
    /// An empty list with room for `capacity` items.
    pub fn with_capacity(capacity: usize) -> Reserved<T> {
        Reserved(Vec::with_capacity(capacity))
    }
}

impl<T: Clone> Clone for Reserved<T> {
    fn clone(&self) -> Self {
        let mut v = Vec::with_capacity(self.0.capacity());
        v.extend_from_slice(&self.0);
        Reserved(v)
    }

    fn clone_from(&mut self, source: &Self) {
        self.0.clear();
        self.0.reserve(source.0.capacity());
        self.0.extend_from_slice(&source.0);
    }
}

impl<T> Deref for Reserved<T> {
    type Target = Vec<T>;
    fn deref(&self) -> &Vec<T> {
        &self.0
    }
}

impl<T> DerefMut for Reserved<T> {
    fn deref_mut(&mut self) -> &mut Vec<T> {
        &mut self.0
    }
}

#[cfg(test)]
mod tests {
    use super::Reserved;

    #[test]
    fn a_clone_has_the_originals_room() {
        let mut a: Reserved<u32> = Reserved::with_capacity(64);
        a.push(1);
        let b = a.clone();
        assert_eq!(&b[..], &[1]);
        assert!(b.capacity() >= 64, "capacity {}", b.capacity());
        let mut c: Reserved<u32> = Reserved::with_capacity(0);
        c.clone_from(&a);
        assert!(c.capacity() >= 64 && c[..] == [1]);
    }
}
