"""Cross-validation of the tape against Vicon (core-only imports): clock offset and transform
(:mod:`.register`), the tape points Vicon markers sit on and segment angles from marker triads
(:mod:`.tape_markers`), and agreement statistics (:mod:`.agreement`)."""
