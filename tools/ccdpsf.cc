// ccdpsf: measure the intrinsic PSF of a CCD from spot-projection exposures.
#include <cstdio>
#include <string>

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: ccdpsf <command> [options]; try 'ccdpsf help'\n");
    return 2;
  }
  std::fprintf(stderr, "ccdpsf: unknown command '%s'\n", argv[1]);
  return 2;
}
