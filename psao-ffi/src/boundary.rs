//! The C boundary: every entry point runs its body through [`call`] or
//! [`call_on`], which catch panics, check pointers and keep the failure's
//! message on the object. Pointer helpers turn C arguments into Rust
//! values only after checking them, and write outputs only on success.

use std::ffi::c_char;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::ptr::NonNull;

use crate::result::{Failure, psao_result};

/// The part of every C object that outlives a failed call: the last
/// failure's message, and whether a panic left the object poisoned.
#[derive(Debug, Default)]
pub(crate) struct ErrorSlot {
    message: String,
    poisoned: bool,
}

impl ErrorSlot {
    /// The last failure's message (empty after a success).
    pub(crate) fn message(&self) -> &str {
        &self.message
    }
}

/// A C object: something with an [`ErrorSlot`].
pub(crate) trait Object {
    /// The object's slot.
    fn slot(&mut self) -> &mut ErrorSlot;
}

thread_local! {
    /// The message of this thread's last failed call that had no object
    /// to keep it (constructors, free functions).
    static THREAD_MESSAGE: std::cell::RefCell<String> = const { std::cell::RefCell::new(String::new()) };
}

/// Runs `body` for a function with no object (constructors, pure
/// functions): a panic becomes `PSAO_ERROR_PANIC`, a failure its code, and
/// the message goes to this thread's slot (`psao_last_error`).
pub(crate) fn call(body: impl FnOnce() -> Result<(), Failure>) -> psao_result {
    let (code, message) = match catch_unwind(AssertUnwindSafe(body)) {
        Ok(Ok(())) => (psao_result::PSAO_OK, String::new()),
        Ok(Err(f)) => (f.code, f.message),
        Err(_) => (
            psao_result::PSAO_ERROR_PANIC,
            "a bug inside psao panicked".to_string(),
        ),
    };
    THREAD_MESSAGE.with(|m| *m.borrow_mut() = message);
    code
}

/// The message of this thread's last failed object-less call.
///
/// # Safety
///
/// As [`write_message`].
pub(crate) unsafe fn thread_last_error(
    buf: *mut c_char,
    cap: usize,
    len: *mut usize,
) -> psao_result {
    THREAD_MESSAGE.with(|m| {
        // SAFETY: the caller's contract on `buf`, `cap` and `len`.
        unsafe { write_message(&m.borrow(), buf, cap, len) }
    })
}

/// Runs `body` on the object behind `object`: NULL is
/// `PSAO_ERROR_NULL_POINTER`, a poisoned object `PSAO_ERROR_PANIC`; a
/// failure's message is kept in the object, a success clears it, and a
/// panic poisons the object.
///
/// # Safety
///
/// `object` is NULL or a pointer returned by the type's `_new` function,
/// not yet freed, and not in use by another thread during the call.
pub(crate) unsafe fn call_on<T: Object>(
    object: *mut T,
    body: impl FnOnce(&mut T) -> Result<(), Failure>,
) -> psao_result {
    if object.is_null() {
        return psao_result::PSAO_ERROR_NULL_POINTER;
    }
    // SAFETY: not NULL, and by the caller's contract it points to a live
    // `T` made by `Box::into_raw` that no one else uses during this call,
    // so a unique reference to it is sound for the call's duration.
    let obj = unsafe { &mut *object };
    if obj.slot().poisoned {
        return psao_result::PSAO_ERROR_PANIC;
    }
    let outcome = catch_unwind(AssertUnwindSafe(|| body(&mut *obj)));
    let slot = obj.slot();
    match outcome {
        Ok(Ok(())) => {
            slot.message.clear();
            psao_result::PSAO_OK
        }
        Ok(Err(f)) => {
            slot.message = f.message;
            f.code
        }
        Err(_) => {
            slot.poisoned = true;
            slot.message = "a bug inside psao panicked; this object is poisoned".into();
            psao_result::PSAO_ERROR_PANIC
        }
    }
}

/// Moves `value` to the heap and writes its pointer to `out`.
///
/// # Safety
///
/// `out` was checked by [`out_ptr`] and is valid for a write.
pub(crate) unsafe fn give<T>(out: NonNull<*mut T>, value: T) {
    let raw = Box::into_raw(Box::new(value));
    // SAFETY: `out` is valid for writes by the caller's contract;
    // `write_unaligned` needs no alignment.
    unsafe { out.as_ptr().write_unaligned(raw) };
}

/// Frees an object made by [`give`]; NULL is ignored.
///
/// # Safety
///
/// `object` is NULL or a pointer from the type's `_new` function that was
/// not freed before and is not in use by another thread.
pub(crate) unsafe fn take<T>(object: *mut T) {
    if object.is_null() {
        return;
    }
    // SAFETY: by the caller's contract `object` came from `Box::into_raw`
    // in `give` and is freed only now.
    let boxed = unsafe { Box::from_raw(object) };
    // The objects' drops (vectors, maps, strings, zstd contexts) do not
    // panic; should one ever, it stops here rather than at the boundary.
    let _ = catch_unwind(AssertUnwindSafe(move || drop(boxed)));
}

/// An output pointer, checked for NULL before any work is done.
pub(crate) fn out_ptr<T>(ptr: *mut T, what: &str) -> Result<NonNull<T>, Failure> {
    NonNull::new(ptr).ok_or_else(|| Failure::null(what))
}

/// Writes an output.
///
/// # Safety
///
/// `out` is valid for a write of `T` (the C caller's contract for every
/// output pointer it passes).
pub(crate) unsafe fn put<T>(out: NonNull<T>, value: T) {
    // SAFETY: valid for writes by the caller's contract; `write_unaligned`
    // needs no alignment and does not read or drop the old, possibly
    // uninitialized, contents.
    unsafe { out.as_ptr().write_unaligned(value) };
}

/// Reads an input passed by pointer.
///
/// # Safety
///
/// `ptr` is NULL or valid for a read of an initialized `T`.
pub(crate) unsafe fn read_in<T: Copy>(ptr: *const T, what: &str) -> Result<T, Failure> {
    if ptr.is_null() {
        return Err(Failure::null(what));
    }
    // SAFETY: not NULL, and valid for reads by the caller's contract;
    // `read_unaligned` does not even need the C side to align it.
    Ok(unsafe { ptr.read_unaligned() })
}

/// An input array of `len` elements; `len == 0` needs no pointer.
///
/// # Safety
///
/// `ptr` is NULL or valid for reads of `len` initialized, aligned `T`s
/// that nothing writes during the call.
pub(crate) unsafe fn slice_in<'a, T>(
    ptr: *const T,
    len: usize,
    what: &str,
) -> Result<&'a [T], Failure> {
    if len == 0 {
        return Ok(&[]);
    }
    check_array(ptr, len, what)?;
    // SAFETY: not NULL, aligned, at most isize::MAX bytes, and valid for
    // reads of `len` elements unchanged during the call by the caller's
    // contract.
    Ok(unsafe { std::slice::from_raw_parts(ptr, len) })
}

/// The rules for a C array of `n > 0` elements: not NULL, at most
/// `isize::MAX` bytes, aligned for `T`.
fn check_array<T>(ptr: *const T, n: usize, what: &str) -> Result<(), Failure> {
    if ptr.is_null() {
        return Err(Failure::null(what));
    }
    if n.checked_mul(size_of::<T>())
        .is_none_or(|b| b > isize::MAX as usize)
    {
        return Err(Failure::invalid(format!(
            "`{what}`: {n} elements are too many"
        )));
    }
    if !ptr.is_aligned() {
        return Err(Failure::invalid(format!("`{what}` is not aligned")));
    }
    Ok(())
}

/// Sets `*len` to `n` and fails with `PSAO_ERROR_BUFFER_TOO_SHORT` when
/// `n` elements do not fit in `cap`.
///
/// # Safety
///
/// `len` is valid for a write.
unsafe fn fits(n: usize, cap: usize, len: NonNull<usize>, what: &str) -> Result<(), Failure> {
    // SAFETY: `len` is valid for a write by the caller's contract.
    unsafe { put(len, n) };
    if n > cap {
        return Err(Failure::new(
            psao_result::PSAO_ERROR_BUFFER_TOO_SHORT,
            format!("`{what}` holds {cap} elements, {n} needed"),
        ));
    }
    Ok(())
}

/// A caller's output array of `cap` elements, checked before any work.
#[derive(Clone, Copy)]
pub(crate) struct OutArray<T> {
    ptr: *mut T,
    cap: usize,
}

impl<T: Copy> OutArray<T> {
    /// Checks `ptr` (NULL only with `cap == 0`) and alignment.
    pub(crate) fn new(ptr: *mut T, cap: usize, what: &str) -> Result<OutArray<T>, Failure> {
        if cap > 0 {
            check_array(ptr.cast_const(), cap, what)?;
        }
        Ok(OutArray { ptr, cap })
    }

    /// The number of elements the array holds.
    pub(crate) fn cap(&self) -> usize {
        self.cap
    }

    /// Writes the `n` items of `items` (an iterator that yields exactly
    /// `n`) without gathering them first; otherwise as [`fill`](Self::fill).
    ///
    /// # Safety
    ///
    /// As [`fill`](Self::fill).
    pub(crate) unsafe fn fill_iter(
        self,
        n: usize,
        items: impl Iterator<Item = T>,
        len: NonNull<usize>,
        what: &str,
    ) -> Result<(), Failure> {
        // SAFETY: `len` is valid for a write by the caller's contract.
        unsafe { fits(n, self.cap, len, what) }?;
        for (i, item) in items.take(n).enumerate() {
            // SAFETY: `i < n <= cap`, and `ptr` is valid and aligned for
            // `cap` writes (the caller's contract, checked in `new`).
            unsafe { self.ptr.add(i).write(item) };
        }
        Ok(())
    }

    /// Copies `items` in and returns `Ok(())`, or writes nothing and fails
    /// with `PSAO_ERROR_BUFFER_TOO_SHORT` when they do not fit. `len`
    /// receives `items.len()` either way.
    ///
    /// # Safety
    ///
    /// The array was valid for writes of `cap` elements (the caller's
    /// contract), and `len` is valid for a write.
    pub(crate) unsafe fn fill(
        self,
        items: &[T],
        len: NonNull<usize>,
        what: &str,
    ) -> Result<(), Failure> {
        // SAFETY: `len` is valid for a write by the caller's contract.
        unsafe { fits(items.len(), self.cap, len, what) }?;
        if !items.is_empty() {
            // SAFETY: `ptr` is valid for `cap >= items.len()` writes and
            // aligned (checked in `new`), and cannot overlap `items`, which
            // is memory psao owns.
            unsafe {
                std::ptr::copy_nonoverlapping(items.as_ptr(), self.ptr, items.len());
            }
        }
        Ok(())
    }
}

/// A C flag: 0 or 1.
pub(crate) fn flag(value: u8, what: &str) -> Result<bool, Failure> {
    match value {
        0 => Ok(false),
        1 => Ok(true),
        v => Err(Failure::invalid(format!("`{what}` is {v}, not 0 or 1"))),
    }
}

/// Writes `message` and a NUL into a caller's buffer: `*len` receives the
/// message's length without the NUL. A buffer shorter than the message and
/// its NUL gets nothing, `PSAO_ERROR_BUFFER_TOO_SHORT`, and in `*len` the
/// bytes needed (the length plus one).
///
/// # Safety
///
/// `buf` is valid for writes of `cap` bytes, `len` for a write.
pub(crate) unsafe fn write_message(
    message: &str,
    buf: *mut c_char,
    cap: usize,
    len: *mut usize,
) -> psao_result {
    let Ok(len) = out_ptr(len, "len") else {
        return psao_result::PSAO_ERROR_NULL_POINTER;
    };
    let out = match OutArray::new(buf.cast::<u8>(), cap, "buf") {
        Ok(out) => out,
        Err(f) => return f.code,
    };
    let bytes = message.bytes().chain([0u8]);
    // SAFETY: the caller's contract on `buf`, `cap` and `len`.
    let r = unsafe { out.fill_iter(message.len() + 1, bytes, len, "buf") };
    if r.is_ok() {
        // SAFETY: as above; on success `*len` is the length without NUL.
        unsafe { put(len, message.len()) };
    }
    match r {
        Ok(()) => psao_result::PSAO_OK,
        Err(f) => f.code,
    }
}

/// The message of `object`'s last failure into a caller's buffer (as
/// [`write_message`]). It does not go through [`call_on`], so it does not
/// clear the message, and works on a poisoned object too.
///
/// # Safety
///
/// `object` is NULL or a live object not in use by another thread; `buf`
/// is valid for writes of `cap` bytes, `len` for a write.
pub(crate) unsafe fn last_error<T: Object>(
    object: *mut T,
    buf: *mut c_char,
    cap: usize,
    len: *mut usize,
) -> psao_result {
    if object.is_null() {
        return psao_result::PSAO_ERROR_NULL_POINTER;
    }
    // SAFETY: not NULL, live and used by this thread only (contract).
    let obj = unsafe { &mut *object };
    // SAFETY: the contract on `buf`, `cap` and `len`.
    unsafe { write_message(obj.slot().message(), buf, cap, len) }
}

/// Three floats (x, y, z) from a C `const float *`.
///
/// # Safety
///
/// `ptr` is NULL or valid for reads of 3 floats.
pub(crate) unsafe fn read_vec3(ptr: *const f32, what: &str) -> Result<glam::Vec3, Failure> {
    if ptr.is_null() {
        return Err(Failure::null(what));
    }
    // SAFETY: not NULL, valid for reads of 3 floats (contract); unaligned
    // reads need no alignment.
    let v = unsafe { [0, 1, 2].map(|i| ptr.add(i).read_unaligned()) };
    Ok(glam::Vec3::from_array(v))
}

/// Copies `all[first..first + count]`, each element through `convert`,
/// into `out` (an array of `count`); `PSAO_ERROR_OUT_OF_RANGE`, writing
/// nothing, when the range is beyond `all`.
///
/// # Safety
///
/// `out` was made from a caller's array valid for writes of `count`
/// elements.
pub(crate) unsafe fn copy_range<S, T: Copy>(
    all: &[S],
    first: u32,
    out: OutArray<T>,
    what: &str,
    convert: impl Fn(&S) -> T,
) -> Result<(), Failure> {
    let count = out.cap();
    let start = first as usize;
    let end = match start.checked_add(count) {
        Some(end) if end <= all.len() => end,
        _ => {
            return Err(Failure::new(
                psao_result::PSAO_ERROR_OUT_OF_RANGE,
                format!(
                    "{what} [{first}, {first} + {count}) beyond the instance's {}",
                    all.len()
                ),
            ));
        }
    };
    let mut written = 0usize;
    let items = all[start..end].iter().map(convert);
    // SAFETY: `out` holds `count == end - start` elements (contract);
    // `written` is a local.
    unsafe { out.fill_iter(end - start, items, (&mut written).into(), what) }
}
