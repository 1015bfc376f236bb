"""What a run did, read back from its log and set against its plan: the report
(:mod:`~dispatcher.review.report`), how well the tractors drove (:mod:`~dispatcher.review.track`)
and the picture (:mod:`~dispatcher.review.plot`)."""
