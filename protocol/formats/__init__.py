"""File formats: BVH (:mod:`.bvh`), gesture scripts (:mod:`.gesture_script`), retargeting recordings
onto the shared skeleton (:mod:`.retarget`), loading either as a motion (:mod:`.load`), the shared
recordings' index (:mod:`.mocap_data`) and H.264 video (:mod:`.video`)."""
