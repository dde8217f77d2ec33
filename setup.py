"""Build the optional compiled EUREKA kernel; rtsid falls back to numpy without a compiler."""

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext


class OptionalBuildExt(build_ext):
    """Build extensions if a C compiler is available; otherwise warn and go on."""

    def run(self) -> None:
        try:
            super().run()
        except Exception as exc:
            print(f"rtsid: compiled EUREKA kernel not built ({exc}); using the numpy fallback")

    def build_extension(self, ext: Extension) -> None:
        try:
            super().build_extension(ext)
        except Exception as exc:
            print(f"rtsid: compiled EUREKA kernel not built ({exc}); using the numpy fallback")


setup(
    ext_modules=[
        Extension(
            "rtsid.ident._eureka",
            sources=["rtsid/ident/_eureka.c"],
            # no fused multiply-adds, whatever CFLAGS say: the kernels repeat numpy's and
            # scipy's roundings (bit-for-bit tests, replay equal to live across builds)
            extra_compile_args=["-O3", "-ffp-contract=off"],
            optional=True,
        )
    ],
    cmdclass={"build_ext": OptionalBuildExt},
)
