"""Print the parameter count of every network at its default size."""

from . import Initializer, LearnedPattern, LightingPredictor, PointPredictor, SVBRDFPredictor, parameter_count

for net in (LearnedPattern(), Initializer(), LightingPredictor(), PointPredictor(), SVBRDFPredictor(),
            SVBRDFPredictor(use_spec=False)):
    extra = " (use_spec=False)" if getattr(net, "use_spec", True) is False else ""
    print(f"{type(net).__name__}{extra}: {parameter_count(net):,} parameters")
