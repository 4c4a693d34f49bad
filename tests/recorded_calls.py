"""The compiled calls a run makes, recorded: to hold against those compiled ahead
(``kernels.compile_ahead``)."""

from softsim.kernels.compile_ahead import argument_types


def recording(make_call, made):
    """``make_call`` (returning a kernel and its arguments, as ``symplectic_euler.advance_driver``
    and ``guard.element_measure_call`` do) that also adds the kernel and its argument types to the
    set ``made``."""
    def make_and_record(*arguments):
        kernel, kernel_arguments = make_call(*arguments)
        made.add((kernel, argument_types(kernel, kernel_arguments)))
        return kernel, kernel_arguments
    return make_and_record
