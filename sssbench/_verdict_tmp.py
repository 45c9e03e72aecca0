import math


def skill(e, e0):
    return 1 - e / e0 if e0 > 0 else math.nan


def is_visible(flip_identity):
    return flip_identity >= 0.005
