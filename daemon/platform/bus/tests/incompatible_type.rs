//! A topic whose service another release's processes created with another
//! layout of its type: opening it says so, and what to do, by name.

use smokenav_platform_bus::{Bus, BusError, BusOptions, Topic};
use smokenav_shared_types::{Health, Odometry};

#[test]
fn a_topic_of_another_type_layout_names_the_service_and_the_remedy() {
    let instance = format!("incompat{}", std::process::id());
    let bus = Bus::open(&BusOptions::new(&instance, "test")).unwrap();
    // The service as one release made it: odometry on this name.
    let _publisher = bus
        .publisher(Topic::<Odometry>::new("test/mismatch"))
        .unwrap();
    // Another release opens it with another type.
    for err in [
        bus.subscriber(Topic::<Health>::new("test/mismatch"))
            .err()
            .expect("a subscriber of another type"),
        bus.publisher(Topic::<Health>::new("test/mismatch"))
            .err()
            .expect("a publisher of another type"),
    ] {
        let service = format!("{instance}/test/mismatch");
        assert!(
            matches!(&err, BusError::IncompatibleType { service: s } if *s == service),
            "{err:?}"
        );
        let text = err.to_string();
        assert!(text.contains(&service), "{text}");
        assert!(text.contains("another smokenav release"), "{text}");
        assert!(text.contains("systemctl restart smokenav.target"), "{text}");
    }
}
