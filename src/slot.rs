//! [`Slot`]: an optional value whose empty state is zero bytes.

/// An optional value, empty as the zero tag.
///
/// `Option<T>` stores `None` in a niche of `T` when it has one (a `bool`'s 2, an enum's first
/// unused discriminant), so a `static` holding an empty one is not all zero bytes and goes to
/// `.data` (flash) instead of `.bss`; the explicit `repr(u8)` gives `Slot` its own tag byte,
/// `Empty` = 0.
#[repr(u8)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Slot<T> {
    /// Nothing.
    Empty = 0,
    /// A value.
    Full(T) = 1,
}

impl<T> Slot<T> {
    /// The value, if any.
    pub const fn get(&self) -> Option<&T> {
        match self {
            Self::Empty => None,
            Self::Full(v) => Some(v),
        }
    }

    /// The value, if any, to change.
    pub fn get_mut(&mut self) -> Option<&mut T> {
        match self {
            Self::Empty => None,
            Self::Full(v) => Some(v),
        }
    }
}
