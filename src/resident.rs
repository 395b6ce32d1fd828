//! Storage a loop writes, made resident before the loop starts. Memory that was reserved but
//! never written is mapped by the kernel on its first write, one page fault a page (7–20 µs
//! on a KVM guest); a ring that the tick walks through would take those faults, one every few
//! samples, for as long as its first lap lasts. Each constructor here writes every element
//! once, so the tick's writes find their pages mapped.

use std::collections::VecDeque;

use crossbeam_channel::{Receiver, Sender};

/// A bounded channel of `capacity` messages whose every slot has been written once (a lap of
/// `filler`s sent and taken). Its slots are written by the stamps that mark them free, but
/// the last slot's message can reach into a page that no stamp lies in: the first lap would
/// fault there.
pub fn channel<T: Clone>(capacity: usize, filler: T) -> (Sender<T>, Receiver<T>) {
    let (tx, rx) = crossbeam_channel::bounded(capacity);
    while tx.try_send(filler.clone()).is_ok() {}
    while rx.try_recv().is_ok() {}
    (tx, rx)
}

/// A deque with room for `capacity` elements whose storage has been written (with `filler`)
/// and emptied again.
pub fn deque<T: Clone>(capacity: usize, filler: T) -> VecDeque<T> {
    let mut d = VecDeque::with_capacity(capacity);
    d.extend(std::iter::repeat_n(filler, d.capacity()));
    d.clear();
    d
}

/// A vector with room for `capacity` elements whose storage has been written (with `filler`)
/// and emptied again.
pub fn vec<T: Clone>(capacity: usize, filler: T) -> Vec<T> {
    let mut v = Vec::with_capacity(capacity);
    v.extend(std::iter::repeat_n(filler, v.capacity()));
    v.clear();
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_storage_is_empty_with_its_room_kept() {
        let d = deque(100, 7u64);
        assert!(d.is_empty());
        assert!(d.capacity() >= 100);
        let v = vec(50, [1.0f64; 4]);
        assert!(v.is_empty());
        assert!(v.capacity() >= 50);
    }

    #[test]
    fn a_channel_comes_empty_with_its_room() {
        let (tx, rx) = channel(16, [0u8; 300]);
        assert!(rx.is_empty());
        assert_eq!(tx.capacity(), Some(16));
        for _ in 0..16 {
            assert!(tx.try_send([1; 300]).is_ok());
        }
        assert!(tx.try_send([2; 300]).is_err());
        assert_eq!(rx.recv().ok(), Some([1; 300]));
    }

    #[test]
    fn a_deque_filled_to_its_room_does_not_grow() {
        let mut d = deque(10, 0u8);
        let room = d.capacity();
        for k in 0..room {
            d.push_back(k as u8);
        }
        assert_eq!(d.capacity(), room);
        assert_eq!(d.len(), room);
    }
}
