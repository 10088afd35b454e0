"""Codecs between motions and the model's pose space: joint angles with the root's motion
(:class:`~bayesmotion.codecs.pose.PoseCodec`) and affective pose features
(:class:`~bayesmotion.codecs.affective.AffectiveCodec`)."""
