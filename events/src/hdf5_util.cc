#include "hdf5_util.h"

namespace evkit::detail {

void H5Handle::reset() {
  if (id_ < 0) return;
  switch (H5Iget_type(id_)) {
    case H5I_FILE:
      H5Fclose(id_);
      break;
    case H5I_GROUP:
      H5Gclose(id_);
      break;
    case H5I_DATASET:
      H5Dclose(id_);
      break;
    case H5I_DATASPACE:
      H5Sclose(id_);
      break;
    case H5I_DATATYPE:
      H5Tclose(id_);
      break;
    case H5I_ATTR:
      H5Aclose(id_);
      break;
    case H5I_GENPROP_LST:
      H5Pclose(id_);
      break;
    default:
      break;
  }
  id_ = H5I_INVALID_HID;
}

void silenceHdf5Errors() { H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr); }

bool linkExists(hid_t loc, const std::string& path) {
  // H5Lexists needs every intermediate group to exist: walk the path.
  size_t pos = 0;
  while (true) {
    const size_t slash = path.find('/', pos);
    const std::string prefix = path.substr(0, slash);
    if (H5Lexists(loc, prefix.c_str(), H5P_DEFAULT) <= 0) return false;
    if (slash == std::string::npos) return true;
    pos = slash + 1;
  }
}

bool attributeExists(hid_t loc, const std::string& name) {
  return H5Aexists(loc, name.c_str()) > 0;
}

namespace {

// Reads an attribute that must hold one number: a scalar, or one element of any rank. H5Aread
// writes the attribute's every element, so a damaged file's array attribute would run past `out`.
void readOneNumber(hid_t loc, const std::string& name, hid_t mem_type, void* out,
                   const std::string& file, const std::string& shown, const char* what) {
  H5Handle attr(H5Aopen(loc, name.c_str(), H5P_DEFAULT));
  if (!attr) throwInFile(file, "cannot open the attribute '" + name + "'");
  H5Handle space(H5Aget_space(attr.get()));
  H5Handle type(H5Aget_type(attr.get()));
  const H5T_class_t kind = type ? H5Tget_class(type.get()) : H5T_NO_CLASS;
  if (!space || H5Sget_simple_extent_npoints(space.get()) != 1 ||
      (kind != H5T_INTEGER && kind != H5T_FLOAT) || H5Aread(attr.get(), mem_type, out) < 0) {
    throwInFile(file, "the attribute '" + (shown.empty() ? name : shown) + "' is not " + what);
  }
}

}  // namespace

int64_t readIntAttribute(hid_t loc, const std::string& name, const std::string& file) {
  int64_t value = 0;
  readOneNumber(loc, name, H5T_NATIVE_INT64, &value, file, "", "one integer");
  return value;
}

double readDoubleAttribute(hid_t loc, const std::string& name, const std::string& file,
                           const std::string& shown) {
  double value = 0;
  readOneNumber(loc, name, H5T_NATIVE_DOUBLE, &value, file, shown, "one number");
  return value;
}

std::vector<int64_t> readIntArrayAttribute(hid_t loc, const std::string& name,
                                           const std::string& file) {
  H5Handle attr(H5Aopen(loc, name.c_str(), H5P_DEFAULT));
  if (!attr) throwInFile(file, "cannot open the attribute '" + name + "'");
  H5Handle space(H5Aget_space(attr.get()));
  const hssize_t n = H5Sget_simple_extent_npoints(space.get());
  if (n < 0 || n > 16) throwInFile(file, "attribute '" + name + "' has an unexpected size");
  std::vector<int64_t> values(static_cast<size_t>(n));
  if (n > 0 && H5Aread(attr.get(), H5T_NATIVE_INT64, values.data()) < 0) {
    throwInFile(file, "cannot read the attribute '" + name + "' as integers");
  }
  return values;
}

void writeIntAttribute(hid_t loc, const std::string& name, int64_t value) {
  H5Handle space(H5Screate(H5S_SCALAR));
  H5Handle attr(
      H5Acreate2(loc, name.c_str(), H5T_STD_I64LE, space.get(), H5P_DEFAULT, H5P_DEFAULT));
  if (!attr || H5Awrite(attr.get(), H5T_NATIVE_INT64, &value) < 0) {
    throw Error("cannot write HDF5 attribute '" + name + "'");
  }
}

void writeStringAttribute(hid_t loc, const std::string& name, const std::string& value) {
  H5Handle type(H5Tcopy(H5T_C_S1));
  H5Tset_size(type.get(), value.size());
  H5Handle space(H5Screate(H5S_SCALAR));
  H5Handle attr(H5Acreate2(loc, name.c_str(), type.get(), space.get(), H5P_DEFAULT, H5P_DEFAULT));
  if (!attr || H5Awrite(attr.get(), type.get(), value.data()) < 0) {
    throw Error("cannot write HDF5 attribute '" + name + "'");
  }
}

std::vector<hsize_t> datasetShape(hid_t dataset) {
  H5Handle space(H5Dget_space(dataset));
  const int rank = H5Sget_simple_extent_ndims(space.get());
  if (rank < 0 || rank > 8) return {};
  std::vector<hsize_t> dims(static_cast<size_t>(rank));
  H5Sget_simple_extent_dims(space.get(), dims.data(), nullptr);
  return dims;
}

}  // namespace evkit::detail
