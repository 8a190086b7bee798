//! Draws SLAM maps on a thread of their own, so the scans never wait for a
//! map: the graph back-end re-draws every node's scan for each map (176 ms
//! for MIT CSAIL's 933 nodes, past a 10 Hz laser's period), and any map
//! grown large costs in proportion.
//!
//! One map at a time: while one is being drawn no other is asked for (the
//! next one due is asked for once it is back), so the work and the memory
//! stay bounded however slow the drawing gets.

use smokenav_algorithms_slam::ExportJob;
use smokenav_platform_map::OccupancyGrid;
use std::sync::mpsc::{self, Receiver, SyncSender, TryRecvError, TrySendError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// A map drawn, for the back-end's map revision it was asked for.
pub struct Drawn {
    pub revision: u64,
    /// The map and the wall cells its footprint cleared; `None` before the first scan.
    pub map: Option<(OccupancyGrid, usize)>,
    /// Wall time the drawing took.
    pub took: Duration,
}

pub struct MapRenderer {
    jobs: Option<SyncSender<(u64, ExportJob)>>,
    done: Receiver<Drawn>,
    busy: bool,
    thread: Option<JoinHandle<()>>,
}

impl MapRenderer {
    pub fn start() -> std::io::Result<Self> {
        let (jobs, todo) = mpsc::sync_channel::<(u64, ExportJob)>(1);
        let (tell, done) = mpsc::sync_channel(1);
        let thread = std::thread::Builder::new()
            .name("slam-map".into())
            .spawn(move || {
                for (revision, job) in todo {
                    let t0 = Instant::now();
                    let map = job();
                    let drawn = Drawn {
                        revision,
                        map,
                        took: t0.elapsed(),
                    };
                    if tell.send(drawn).is_err() {
                        break;
                    }
                }
            })?;
        Ok(Self {
            jobs: Some(jobs),
            done,
            busy: false,
            thread: Some(thread),
        })
    }

    /// The thread is there to draw (it is gone only if a drawing panicked).
    pub fn alive(&self) -> bool {
        self.jobs.is_some()
    }

    /// No map is being drawn.
    pub fn idle(&self) -> bool {
        self.alive() && !self.busy
    }

    /// Asks for `job`'s map; false (and nothing asked) while another is drawn.
    pub fn draw(&mut self, revision: u64, job: ExportJob) -> bool {
        let Some(jobs) = &self.jobs else {
            return false;
        };
        if self.busy {
            return false;
        }
        match jobs.try_send((revision, job)) {
            Ok(()) => {
                self.busy = true;
                true
            }
            Err(TrySendError::Full(_)) => false,
            Err(TrySendError::Disconnected(_)) => {
                self.jobs = None;
                false
            }
        }
    }

    /// The map drawn since the last call, if one is back. `Err` once: the
    /// thread died (a drawing panicked); from then on maps are drawn in place.
    pub fn finished(&mut self) -> Result<Option<Drawn>, &'static str> {
        if self.jobs.is_none() {
            return Ok(None);
        }
        match self.done.try_recv() {
            Ok(d) => {
                self.busy = false;
                Ok(Some(d))
            }
            Err(TryRecvError::Empty) => Ok(None),
            Err(TryRecvError::Disconnected) => {
                self.jobs = None;
                self.busy = false;
                Err("the map drawing thread stopped (a drawing panicked): maps are drawn in place")
            }
        }
    }
}

impl Drop for MapRenderer {
    fn drop(&mut self) {
        // Closing the queue ends the thread after the drawing in hand.
        self.jobs = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn wait(r: &mut MapRenderer) -> Drawn {
        let end = Instant::now() + Duration::from_secs(10);
        loop {
            if let Some(d) = r.finished().unwrap() {
                return d;
            }
            assert!(Instant::now() < end, "no map back");
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    #[test]
    fn one_map_at_a_time_and_each_comes_back_with_its_revision() {
        let mut r = MapRenderer::start().unwrap();
        let (go, gate) = mpsc::channel::<()>();
        let job: ExportJob = Box::new(move || {
            gate.recv().unwrap();
            Some((OccupancyGrid::new(3, 2, 0.05, [0.0; 3]), 4))
        });
        assert!(r.draw(7, job));
        assert!(!r.idle());
        // A second one while the first is drawn is not taken.
        assert!(!r.draw(8, Box::new(|| None)));
        assert!(r.finished().unwrap().is_none());
        go.send(()).unwrap();
        let d = wait(&mut r);
        assert_eq!(d.revision, 7);
        let (map, cleared) = d.map.unwrap();
        assert_eq!((map.width, map.height, cleared), (3, 2, 4));
        assert!(r.idle());
        assert!(r.draw(9, Box::new(|| None)));
        assert_eq!(wait(&mut r).revision, 9);
    }

    #[test]
    fn a_drawing_that_panics_is_reported_once_and_nothing_hangs() {
        let mut r = MapRenderer::start().unwrap();
        assert!(r.draw(1, Box::new(|| panic!("drawing failed"))));
        let end = Instant::now() + Duration::from_secs(10);
        let err = loop {
            match r.finished() {
                Err(e) => break e,
                Ok(None) => {
                    assert!(Instant::now() < end, "the death went unnoticed");
                    std::thread::sleep(Duration::from_millis(5));
                }
                Ok(Some(_)) => panic!("a map from a panicked drawing"),
            }
        };
        assert!(err.contains("drawn in place"), "{err}");
        assert!(!r.alive() && !r.idle());
        assert!(!r.draw(2, Box::new(|| None)));
        assert!(r.finished().unwrap().is_none());
    }
}
