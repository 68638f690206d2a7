"""One error type for every problem in a scene, naming the field at fault."""


class SceneError(ValueError):
    """A scene cannot be used: `field` is a dotted path (``objects[2].shape.path``), `problem` says why."""

    def __init__(self, field: str, problem: str):
        self.field = field
        self.problem = problem
        super().__init__(f"{field}: {problem}")

    def __reduce__(self):  # pickled whole across processes (Ray, the API's geometry processes)
        return (SceneError, (self.field, self.problem))
