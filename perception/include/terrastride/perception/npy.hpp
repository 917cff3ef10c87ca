// Minimal NPY (NumPy .npy v1/v2/v3) support: 2-D C-order little-endian arrays, for terrain layers
// (write) and for reading clouds and layers back (tests, read_cloud).
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace terrastride::perception {

// Writes a 2-D array (rows x cols, row-major) atomically. Throws InputError naming the path on
// failure.
void write_npy(const std::string& path, const float* data, size_t rows, size_t cols);
void write_npy(const std::string& path, const double* data, size_t rows, size_t cols);
void write_npy(const std::string& path, const uint8_t* data, size_t rows, size_t cols);

struct NpyArray {
  std::string dtype;           // numpy descr as in the file, e.g. "<f4", "<f8", "|u1"
  std::vector<size_t> shape;   // 1-D arrays have one entry
  bool fortran_order = false;  // always false: Fortran-order files are reordered to C order
  std::vector<char> bytes;     // raw little-endian data, size = product(shape) * itemsize
  size_t item_size = 0;
  size_t rows() const { return shape.empty() ? 0 : shape[0]; }
  size_t cols() const { return shape.size() < 2 ? 1 : shape[1]; }
  // Element (r, c) as double (dtypes <f4 <f8 |u1 <i4 <i8); no bounds check beyond an assert.
  double at(size_t r, size_t c) const;
};

// Reads a 1-D or 2-D array of dtype <f4 <f8 |u1 <i4 <i8 (Fortran order is reordered to C order).
// Throws InputError naming the file on a bad magic/header, a big-endian, structured or other dtype,
// or a data section shorter or longer than the header's shape.
NpyArray read_npy(const std::string& path);

}  // namespace terrastride::perception
